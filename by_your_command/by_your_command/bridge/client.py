"""Agent-side asyncio client for the bridge (no ROS needed): rosbridge v2 over WebSocket.

- A supervisor task connects, replays advertisements and subscriptions, reads, and reconnects
  with capped exponential backoff and jitter for as long as the client runs. Nothing the bridge
  sends and no `on_status` callback can end it: errors are contained, counted and logged.
  Only close() and an HTTP 401/403 refusal (unless `retry_refusals`) stop it.
- Received messages wait in per-class lanes (`client_inbox`): receive() serves commands first,
  then state (latest wins), then audio/text/video in arrival order. Audio, text and commands are
  never dropped here: when their lane is full the client stops reading the socket, so the bridge
  counts and reports the loss, which comes out of receive() as a `Lost` in order.
- receive() raises `ClientStopped` (after draining what was received) once the client is closed,
  refused or failed, instead of waiting forever.
- Service calls and action goals (call_service, send_action_goal) are sent now or refused with an
  exception; once sent, exactly one final delivery comes for each: a ServiceReply or GoalResult
  from the bridge, or a failure made here (code "disconnected" when the connection drops, as the
  bridge cancels a departed client's goals; "timeout" when a service reply is long overdue;
  "not_active" when the bridge answers a cancel with no such goal). GoalFeedback is latest-wins.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus, WebSocketException

from by_your_command.bridge.client_inbox import Inbox, InboxLimits
from by_your_command.bridge.client_messages import (
    BridgeRefused,
    BridgeUnavailable,
    ClientClosed,
    ClientFailed,
    ClientHealth,
    ClientStopped,
    Delivery,
    GoalFeedback,
    GoalResult,
    Lost,
    Received,
    ServiceReply,
    TooManyCalls,
    zero_per_class,
)
from by_your_command.bridge.client_topics import TopicClasses, default_class
from by_your_command.bridge.client_wire import (
    PublishFrame,
    ServerFrameError,
    StatusFrame,
    encode_publish,
    parse_server_frame,
)
from by_your_command.bridge.config import TOPIC_CLASSES, TopicClass
from by_your_command.bridge.protocol import (
    Advertise,
    CallService,
    CancelActionGoal,
    Request,
    RequestId,
    SendActionGoal,
    Status,
    Subscribe,
    Unadvertise,
    Unsubscribe,
    encode_request,
    normalize_interface,
    normalize_type,
    parse_request,
)
from by_your_command.net.backoff import backoff_s
from by_your_command.net.quiet_websockets import quiet_websocket_logger

__all__ = [
    "BridgeClient",
    "BridgeRefused",
    "BridgeUnavailable",
    "ClientClosed",
    "ClientFailed",
    "ClientHealth",
    "ClientOptions",
    "ClientStopped",
    "Delivery",
    "GoalFeedback",
    "GoalResult",
    "Lost",
    "Received",
    "ServiceReply",
    "TooManyCalls",
]

log = logging.getLogger(__name__)
_QUIET_WEBSOCKET_LOG = quiet_websocket_logger(__name__)

# Bridge status codes that report messages that will never arrive, and what the agent is told.
_LOSS_REASONS = {
    "dropped": "the bridge dropped them (this client fell behind)",
    "lost": "lost before the bridge (ROS history overwritten)",
}


@dataclass(frozen=True)
class ClientOptions:
    token: str = ""
    receive_queue: int = 1000  # audio + text messages buffered before the client stops reading
    command_queue: int = 256  # command messages buffered before the client stops reading
    state_keys_per_topic: int = 32  # pending latest-wins values per state topic (one per key)
    state_key_fields: tuple[tuple[str, str], ...] = (("playback_status", "stream_id"),)
    backoff_initial_s: float = 0.1
    backoff_max_s: float = 5.0
    stable_after_s: float = 5.0  # a connection that lasted this long resets the backoff
    open_timeout_s: float = 5.0
    close_timeout_s: float = 2.0
    max_message_bytes: int = 16 * 1024 * 1024
    retry_refusals: bool = False  # a 401 is a configuration error, not a transient one
    status_history: int = 100  # recent bridge statuses kept in `statuses`
    max_outstanding_calls: int = 64  # service calls + goals sent and not yet answered
    # A service call without timeout_s is failed here ("timeout") if no reply came after this long
    # (plus reply_grace_s): its request may have been refused before the bridge could read its id.
    reply_timeout_s: float = 120.0
    reply_grace_s: float = 10.0  # added to every call's own timeout_s: the bridge answers first

    def __post_init__(self) -> None:
        if not 0 < self.backoff_initial_s <= self.backoff_max_s:
            raise ValueError("need 0 < backoff_initial_s <= backoff_max_s")
        if self.receive_queue < 1 or self.command_queue < 1 or self.status_history < 1:
            raise ValueError("receive_queue, command_queue and status_history must be at least 1")
        if self.max_outstanding_calls < 1 or not self.reply_timeout_s > 0 or not self.reply_grace_s >= 0:
            raise ValueError("need max_outstanding_calls >= 1, reply_timeout_s > 0 and reply_grace_s >= 0")

    def inbox_limits(self) -> InboxLimits:
        return InboxLimits(
            self.receive_queue, self.command_queue, self.state_keys_per_topic, self.state_key_fields
        )


@dataclass
class _Outstanding:
    """A call or goal sent and not yet answered."""

    kind: str  # "service" or "goal"
    name: str  # the service or action, as sent
    expiry: asyncio.TimerHandle | None = None


def _worth_logging(count: int) -> bool:
    """The first ten of a kind, then every hundredth: visible, but a hostile peer cannot flood the log."""
    return count <= 10 or count % 100 == 0


class BridgeClient:
    def __init__(
        self,
        url: str,
        options: ClientOptions | None = None,
        on_status: Callable[[Status], None] | None = None,
    ) -> None:
        self.url = url
        self.options = options or ClientOptions()
        self._on_status = on_status
        self._subscriptions: dict[str, Subscribe] = {}
        self._advertised: dict[str, Advertise] = {}
        self._outstanding: dict[RequestId, _Outstanding] = {}
        self._classes = TopicClasses()
        self._inbox = Inbox(self.options.inbox_limits())
        self._arrived = asyncio.Event()  # something was queued, or the client stopped
        self._space = asyncio.Event()  # the consumer made room: reading may resume
        self._connected = asyncio.Event()
        self._requests = asyncio.Lock()  # replay and (un)subscribe/(un)advertise never interleave
        self._connection: ClientConnection | None = None
        self._runner: asyncio.Task[None] | None = None
        self._stop_reason: ClientStopped | None = None  # template; receive() raises a fresh copy
        self._stopped = asyncio.Event()
        self._rng = random.Random()
        self.refusal: BridgeRefused | None = None
        self.statuses: deque[Status] = deque(maxlen=self.options.status_history)  # newest last
        self.connects = 0
        self._connection_failures = 0
        self._protocol_errors = 0
        self._callback_errors = 0
        self._internal_errors = 0
        self._bridge_dropped = zero_per_class()
        self._unknown_losses = 0
        self._reading_paused = False
        self._pauses = 0
        self._last_error = ""

    # --- lifecycle ---------------------------------------------------------------------------

    async def start(self) -> None:
        if self._stop_reason is not None:
            raise self._stopped_error()
        if self._runner is None:
            self._runner = asyncio.create_task(self._supervise(), name=f"bridge-client {self.url}")
            self._runner.add_done_callback(self._supervisor_ended)

    async def wait_connected(self, timeout: float | None = None) -> None:
        """Until connected; raises BridgeRefused/ClientStopped if the client stops, BridgeUnavailable
        on timeout."""
        if self._runner is None and self._stop_reason is None:
            raise BridgeUnavailable("the client was not started (use start() or `async with`)")
        connected = asyncio.ensure_future(self._connected.wait())
        stopped = asyncio.ensure_future(self._stopped.wait())
        try:
            await asyncio.wait({connected, stopped}, timeout=timeout, return_when=asyncio.FIRST_COMPLETED)
        finally:
            connected.cancel()
            stopped.cancel()
        if self._connected.is_set():
            return
        if self._stop_reason is not None:
            raise self._stopped_error()
        raise BridgeUnavailable(f"not connected to {self.url} within {timeout} s")

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def running(self) -> bool:
        return self._runner is not None and self._stop_reason is None

    async def close(self) -> None:
        self._stop(ClientClosed(f"the client of {self.url} was closed"))
        connection = self._connection
        if connection is not None:
            with contextlib.suppress(Exception):  # a clean close (1000) if the bridge answers in time
                await connection.close()
        runner, self._runner = self._runner, None
        if runner is not None:
            runner.cancel()
            try:
                await runner
            except asyncio.CancelledError:
                pass
            except Exception:  # already reported by _supervisor_ended; close() itself must not fail
                log.debug("supervisor ended with an error while closing", exc_info=True)
        self._connected.clear()

    async def __aenter__(self) -> BridgeClient:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # --- requests ----------------------------------------------------------------------------

    async def subscribe(
        self,
        topic: str,
        msg_type: str | None = None,
        throttle_rate_ms: int = 0,
        queue_length: int = 0,
        topic_class: TopicClass | None = None,
    ) -> None:
        """Receive `topic` (replayed after every reconnect). `topic_class` picks the delivery lane;
        by default the topic contract's class (docs/topics.md), else guessed from the type."""
        if topic_class is not None and topic_class not in TOPIC_CLASSES:
            raise ValueError(f"topic_class must be one of {TOPIC_CLASSES}, got {topic_class!r}")
        normalized = normalize_type(msg_type) if msg_type else None
        request = Subscribe(topic, normalized, throttle_rate_ms, queue_length)
        async with self._requests:
            self._subscriptions[topic] = request
            self._classes.set(topic, topic_class or default_class(topic, normalized))
            await self._send_if_connected(request)

    async def unsubscribe(self, topic: str) -> None:
        async with self._requests:
            if self._subscriptions.pop(topic, None) is not None:
                self._classes.remove(topic)
                await self._send_if_connected(Unsubscribe(topic))

    async def advertise(self, topic: str, msg_type: str) -> None:
        request = Advertise(topic, normalize_type(msg_type))
        async with self._requests:
            self._advertised[topic] = request
            await self._send_if_connected(request)

    async def unadvertise(self, topic: str) -> None:
        async with self._requests:
            if self._advertised.pop(topic, None) is not None:
                await self._send_if_connected(Unadvertise(topic))

    async def publish(self, topic: str, msg: dict[str, Any], request_id: str | int | None = None) -> None:
        """Send now or raise: BridgeUnavailable while disconnected (stale commands are never
        replayed later), ClientStopped once closed, ValueError/TypeError for a message that is
        not JSON (NaN included). A refusal by the bridge comes back as a status (`request_id`)."""
        connection = self._open_connection(f"cannot publish on {topic!r}")
        frame = encode_publish(topic, msg, request_id)
        try:
            await connection.send(frame)
        except ConnectionClosed as error:
            raise BridgeUnavailable(f"connection lost while publishing on {topic!r}") from error

    async def call_service(
        self,
        service: str,
        args: dict[str, Any],
        request_id: RequestId,
        service_type: str | None = None,
        timeout_s: float | None = None,
    ) -> None:
        """Call a service through the bridge; its ServiceReply (same id) comes out of receive().

        Raises like publish() (BridgeUnavailable, ClientStopped), plus ValueError for a request the
        bridge would refuse anyway (bad name, type, timeout, NaN; an id already outstanding) and
        TooManyCalls. `timeout_s`: how long the bridge waits (it may allow less)."""
        normalized = normalize_interface(service_type, "srv") if service_type else None
        request = CallService(service, args, request_id, normalized, timeout_s)
        expires = (timeout_s or self.options.reply_timeout_s) + self.options.reply_grace_s
        await self._send_call(request, _Outstanding("service", service), expires)

    async def send_action_goal(
        self, action: str, action_type: str, args: dict[str, Any], request_id: RequestId
    ) -> None:
        """Send a goal (with feedback); GoalFeedback and one GoalResult (same id) come out of receive().
        Raises like call_service()."""
        request = SendActionGoal(action, normalize_interface(action_type, "action"), args, request_id, True)
        await self._send_call(request, _Outstanding("goal", action), None)

    async def cancel_action_goal(self, action: str, request_id: RequestId) -> None:
        """Ask the bridge to cancel the goal sent with `request_id`; its GoalResult still comes (status
        5 canceled, or how it ended first). Nothing is sent for a goal that already ended here.
        Raises BridgeUnavailable while disconnected (its goals were failed and cancelled already)."""
        connection = self._open_connection(f"cannot cancel goal {request_id!r}")
        entry = self._outstanding.get(request_id)
        if entry is None or entry.kind != "goal":
            log.debug("cancel of goal %r that is not active here: not sent", request_id)
            return
        try:
            await connection.send(encode_request(CancelActionGoal(action, request_id)))
        except ConnectionClosed as error:
            raise BridgeUnavailable(f"connection lost while cancelling goal {request_id!r}") from error

    def _open_connection(self, what: str) -> ClientConnection:
        if self._stop_reason is not None:
            raise self._stopped_error()
        connection = self._connection
        if connection is None or not self._connected.is_set():
            raise BridgeUnavailable(f"{what}: not connected to {self.url}")
        return connection

    async def _send_call(
        self, request: CallService | SendActionGoal, entry: _Outstanding, expires_s: float | None
    ) -> None:
        connection = self._open_connection(f"cannot send {entry.kind} {entry.name!r}")
        if request.id in self._outstanding:
            raise ValueError(f"request id {request.id!r} is already outstanding: ids must be unique")
        if len(self._outstanding) >= self.options.max_outstanding_calls:
            raise TooManyCalls(
                f"{len(self._outstanding)} calls and goals already outstanding "
                f"(max_outstanding_calls {self.options.max_outstanding_calls})"
            )
        frame = encode_request(request)  # ValueError for NaN/inf
        parse_request(frame)  # what the bridge would refuse (a ProtocolError, a ValueError), said now
        if expires_s is not None:
            loop = asyncio.get_running_loop()
            entry.expiry = loop.call_later(expires_s, self._expire, request.id, entry, expires_s)
        self._outstanding[request.id] = entry  # before sending: the reply may come at once
        try:
            await connection.send(frame)
        except ConnectionClosed as error:
            if self._outstanding.get(request.id) is not entry:
                return  # the drop already failed it: that delivery is its one answer
            self._forget_call(request.id)
            raise BridgeUnavailable(f"connection lost while sending {entry.kind} {entry.name!r}") from error

    def _forget_call(self, request_id: RequestId) -> _Outstanding | None:
        entry = self._outstanding.pop(request_id, None)
        if entry is not None and entry.expiry is not None:
            entry.expiry.cancel()
        return entry

    def _expire(self, request_id: RequestId, entry: _Outstanding, after_s: float) -> None:
        if self._outstanding.get(request_id) is not entry:
            return
        self._forget_call(request_id)
        self._deliver_failure(request_id, entry, f"no reply from the bridge within {after_s:g} s", "timeout")

    def _deliver_failure(self, request_id: RequestId, entry: _Outstanding, error: str, code: str) -> None:
        if entry.kind == "service":
            self._inbox.put_reply(ServiceReply(request_id, entry.name, False, None, error, code))
        else:
            self._inbox.put_reply(GoalResult(request_id, entry.name, False, 0, None, error, code))
        self._arrived.set()

    def _fail_outstanding(self, reason: str) -> None:
        """The connection dropped: the bridge cancels our goals and forgets our calls, so each gets
        its failure now; nobody waits for ever."""
        for request_id in list(self._outstanding):
            entry = self._forget_call(request_id)
            if entry is not None:
                self._deliver_failure(request_id, entry, reason, "disconnected")

    async def receive(self, timeout: float | None = None) -> Delivery:
        """The next delivery (commands, then state, then audio/text/video). Raises TimeoutError
        after `timeout`, ClientStopped once the client stopped and everything received was read."""
        item = self._take()
        if item is not None:
            return item
        try:
            return await asyncio.wait_for(self._wait_for_delivery(), timeout)
        except asyncio.TimeoutError:  # the builtin one on every Python (they differ on 3.10)
            raise TimeoutError(f"nothing received within {timeout} s") from None

    def receive_nowait(self) -> Delivery | None:
        """The next delivery or None; raises ClientStopped once stopped and drained."""
        item = self._take()
        if item is None and self._stop_reason is not None:
            raise self._stopped_error()
        return item

    # --- health ------------------------------------------------------------------------------

    def health(self) -> ClientHealth:
        return ClientHealth(
            running=self.running,
            connected=self.connected,
            connects=self.connects,
            reconnects=max(0, self.connects - 1),
            connection_failures=self._connection_failures,
            protocol_errors=self._protocol_errors,
            callback_errors=self._callback_errors,
            internal_errors=self._internal_errors,
            outstanding_calls=len(self._outstanding),
            feedback_dropped=self._inbox.feedback_dropped,
            queued=self._inbox.queued(),
            dropped=dict(self._inbox.dropped),
            bridge_dropped=dict(self._bridge_dropped),
            unknown_losses=self._unknown_losses,
            reading_paused=self._reading_paused,
            reading_pauses=self._pauses,
            last_error=self._last_error,
        )

    @property
    def dropped(self) -> int:
        """Values replaced in this client before being read (state and video only)."""
        return sum(self._inbox.dropped.values())

    # --- receiving ---------------------------------------------------------------------------

    def _take(self) -> Delivery | None:
        item = self._inbox.pop()
        if item is not None and self._reading_paused and not self._inbox.full:
            self._space.set()
        return item

    async def _wait_for_delivery(self) -> Delivery:
        while True:
            # Look before clearing: wait_for may start this coroutine after the reader queued items.
            item = self._take()
            if item is not None:
                return item
            if self._stop_reason is not None:
                raise self._stopped_error()
            if self._runner is None:
                raise BridgeUnavailable("the client was not started (use start() or `async with`)")
            self._arrived.clear()
            await self._arrived.wait()

    async def _read(self, connection: ClientConnection) -> None:
        async for frame in connection:
            try:
                self._handle(frame)
            except Exception as error:  # a bug of ours must not end reading: count, log, go on
                self._internal_error("handling a bridge frame", error)
            if self._inbox.full:  # back-pressure: the bridge's queue for us fills and it reports drops
                self._reading_paused = True
                self._pauses += 1
                if _worth_logging(self._pauses):
                    log.warning(
                        "receive lanes full %s: reading paused (%d times)", self._inbox.queued(), self._pauses
                    )
                self._space.clear()
                await self._space.wait()
                self._reading_paused = False

    def _handle(self, frame: str | bytes) -> None:
        try:
            parsed = parse_server_frame(frame)
        except ServerFrameError as error:
            self._protocol_error(str(error))
            return
        if isinstance(parsed, PublishFrame):
            topic = parsed.topic
            self._inbox.put(Received(topic, self._classes.class_of(topic), parsed.msg, time.monotonic()))
            self._arrived.set()
        elif isinstance(parsed, StatusFrame):
            self._handle_status(parsed)
        else:
            self._handle_reply(parsed)

    def _handle_reply(self, reply: ServiceReply | GoalFeedback | GoalResult) -> None:
        kind = "service" if isinstance(reply, ServiceReply) else "goal"
        entry = self._outstanding.get(reply.id)
        if entry is None or entry.kind != kind:
            self._protocol_error(
                f"{type(reply).__name__} for id {reply.id!r}, which has no {kind} outstanding"
            )
            return
        if isinstance(reply, GoalFeedback):
            self._inbox.put_feedback(reply)
        else:
            self._forget_call(reply.id)
            self._inbox.put_reply(reply)
        self._arrived.set()

    def _handle_status(self, frame: StatusFrame) -> None:
        status = frame.status
        if frame.defects:
            self._protocol_error(f"status with malformed fields: {'; '.join(frame.defects)}")
        self.statuses.append(status)
        if status.level != "info":
            log.warning("bridge %s [%s]: %s", status.level, status.code[:40] or "-", status.msg[:300])
        if status.code == "not_active" and status.id is not None:
            entry = self._outstanding.get(status.id)
            if entry is not None and entry.kind == "goal":  # the bridge has no such goal: it never ran
                self._forget_call(status.id)
                self._deliver_failure(status.id, entry, status.msg, "not_active")
        reason = _LOSS_REASONS.get(status.code)
        if reason is not None:
            now = time.monotonic()
            for reported, count in status.counts.items():
                topic = self._classes.resolve(reported)
                topic_class = self._classes.class_of(topic)
                self._bridge_dropped[topic_class] += count
                self._inbox.put_lost(Lost(topic, topic_class, count, reason, now))
            self._arrived.set()
        if self._on_status is not None:
            try:
                self._on_status(status)
            except Exception as error:  # the agent's bug: contained, the client goes on
                self._callback_errors += 1
                self._last_error = f"on_status raised {error!r}"
                if _worth_logging(self._callback_errors):
                    log.exception("on_status callback raised (%d so far)", self._callback_errors)

    # --- supervisor --------------------------------------------------------------------------

    async def _supervise(self) -> None:
        loop = asyncio.get_running_loop()
        attempt = 0
        while self._stop_reason is None:
            started = loop.time()
            try:
                await self._connect_and_read()
            except InvalidStatus as error:
                status = error.response.status_code
                self._failure(f"bridge refused the connection: HTTP {status}")
                if not self.options.retry_refusals and status in (401, 403):
                    self.refusal = BridgeRefused(f"bridge refused the connection: HTTP {status}")
                    log.error("%s; not retrying (check the token)", self.refusal)
                    self._stop(self.refusal)
                    return
            except (OSError, WebSocketException, asyncio.TimeoutError) as error:
                self._failure(f"bridge connection failed or lost: {error!r}")
            except Exception as error:  # never let one surprise end reconnecting: count, log, retry
                self._internal_error("in the connection loop", error)
            if self._stop_reason is not None:
                return
            attempt = 0 if loop.time() - started >= self.options.stable_after_s else attempt + 1
            options = self.options  # backoff_s counts from 1; attempt 0 here: a stable connection lost
            await asyncio.sleep(
                backoff_s(attempt + 1, options.backoff_initial_s, options.backoff_max_s, self._rng.uniform)
            )

    async def _connect_and_read(self) -> None:
        headers = {"Authorization": f"Bearer {self.options.token}"} if self.options.token else None
        async with connect(
            self.url,
            additional_headers=headers,
            compression=None,
            max_size=self.options.max_message_bytes,
            open_timeout=self.options.open_timeout_s,
            close_timeout=self.options.close_timeout_s,
            proxy=None,  # the bridge is local or on the robot LAN, never behind a web proxy
            logger=_QUIET_WEBSOCKET_LOG,
        ) as connection:
            async with self._requests:
                replay: list[Request] = [*self._advertised.values(), *self._subscriptions.values()]
                for request in replay:
                    await connection.send(encode_request(request))
                self._connection = connection
                self.connects += 1
                self._connected.set()
            log.info("connected to %s (connection %d)", self.url, self.connects)
            try:
                await self._read(connection)
            finally:
                self._connection = None
                self._connected.clear()
                self._fail_outstanding("connection to the bridge lost")
                if self._stop_reason is None:
                    self._report_disconnection()
        if self._stop_reason is None:  # a clean close by the bridge (restart, shutdown) is a loss too
            self._failure(f"the bridge closed the connection (code {connection.close_code})")

    def _report_disconnection(self) -> None:
        """What the bridge had queued for us, and anything published until we are back, is gone:
        tell the consumer in order, per topic that cannot be refreshed (state is replayed on
        resubscribe, video is only ever the latest frame)."""
        now = time.monotonic()
        for topic, topic_class in self._classes.items():
            if topic_class in ("audio", "text", "command"):
                self._unknown_losses += 1
                self._inbox.put_lost(Lost(topic, topic_class, None, "connection to the bridge lost", now))
        self._arrived.set()

    def _supervisor_ended(self, task: asyncio.Task[None]) -> None:
        if self._stop_reason is not None:
            return
        error = None if task.cancelled() else task.exception()
        failed = ClientFailed(f"the client's supervisor ended unexpectedly: {error!r}")
        failed.__cause__ = error
        log.error("%s", failed, exc_info=error)
        self._stop(failed)

    def _stop(self, reason: ClientStopped) -> None:
        if self._stop_reason is None:
            self._stop_reason = reason
            self._stopped.set()
            self._arrived.set()  # wake receive() so it can drain and then raise
            self._space.set()

    def _stopped_error(self) -> ClientStopped:
        reason = self._stop_reason
        assert reason is not None
        fresh = type(reason)(str(reason))  # a new instance each time: tracebacks do not pile up
        fresh.__cause__ = reason.__cause__
        return fresh

    def _failure(self, message: str) -> None:
        self._connection_failures += 1
        self._last_error = message
        level = logging.INFO if _worth_logging(self._connection_failures) else logging.DEBUG
        log.log(level, "%s", message)

    def _protocol_error(self, message: str) -> None:
        self._protocol_errors += 1
        self._last_error = message
        if _worth_logging(self._protocol_errors):
            log.warning("ignoring a frame from the bridge (%d so far): %s", self._protocol_errors, message)

    def _internal_error(self, where: str, error: Exception) -> None:
        self._internal_errors += 1
        self._last_error = f"{where}: {error!r}"
        if _worth_logging(self._internal_errors):
            log.error("unexpected error %s (%d so far)", where, self._internal_errors, exc_info=error)

    async def _send_if_connected(self, request: Request) -> None:
        connection = self._connection
        if connection is not None and self._connected.is_set():
            with contextlib.suppress(ConnectionClosed):  # replayed on the next connect
                await connection.send(encode_request(request))
