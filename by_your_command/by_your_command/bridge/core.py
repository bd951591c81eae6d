"""The bridge's protocol logic, independent of sockets and of ROS.

`BridgeCore` validates every request against the allow-lists, keeps per-client state and routes
ROS messages (already JSON-encoded once) into each subscriber's bounded send queue. It talks to
ROS only through the small `RosGraph` port, so tests drive it with a fake graph.
All methods run on the asyncio loop's thread, except `_prepare` (parse + convert, pure), which
runs on a worker thread for frames larger than `inline_convert_bytes`: one client's 1 MB publish
must not stall every other client's audio. Each client has at most one frame on a worker at a
time (its frames stay in order, and a heavy client cannot take all workers); the frames waiting
behind it are bounded, and the server stops reading from that client while the bound is reached.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass, field, fields
from typing import Any, Protocol

from by_your_command.bridge.config import AllowLists, BridgeParams, TopicRule
from by_your_command.bridge.flow import LogLimiter, SendQueue, TokenBucket
from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.protocol import (
    Advertise,
    ProtocolError,
    Publish,
    Request,
    RequestId,
    Status,
    Subscribe,
    Unadvertise,
    Unsubscribe,
    encode_publish,
    encode_status,
    parse_request,
    preview,
    utf8_size,
)

log = logging.getLogger(__name__)

MAX_STATUS_MESSAGE_CHARS = 300  # status texts quote client input: keep replies small whatever it was
STOPPING = "the bridge is stopping: request not handled"


class PublishError(ValueError):
    """A client message that cannot become a ROS message (wrong fields or types)."""


class RosGraph(Protocol):
    """What the core needs from ROS. Called only from the loop thread, except `convert`."""

    def subscribe(self, rule: TopicRule, full_topic: str) -> None:
        """Start delivering `full_topic` to `BridgeCore.deliver` (idempotent).

        Topics of class `state` should be delivered even without subscribers: the core keeps
        their last value for clients that subscribe later.
        """

    def unsubscribe(self, full_topic: str) -> None:
        """No client wants `full_topic` any more."""

    def advertise(self, rule: TopicRule, full_topic: str) -> None:
        """Make sure a publisher exists (idempotent)."""

    def convert(self, rule: TopicRule, msg: dict[str, Any]) -> Any:
        """JSON object → ROS message; raise PublishError with a client-facing message on bad content.

        May run on a worker thread, several at once: must not touch shared mutable state.
        """

    def publish(self, rule: TopicRule, full_topic: str, message: Any) -> None:
        """Publish what `convert` returned; raise PublishError if ROS refuses it."""


@dataclass
class _Subscription:
    client_topic: str  # the name as the client wrote it: frames carry it back unchanged
    rule: TopicRule
    throttle_s: float
    queue_length: int
    last_sent: float = float("-inf")
    throttled: int = 0


@dataclass
class ClientSession:
    peer: str
    queue: SendQueue
    limiter: TokenBucket
    id: int = 0
    subscriptions: dict[str, _Subscription] = field(default_factory=dict)  # by full topic
    advertised: set[str] = field(default_factory=set)
    received: int = 0
    rejected: int = 0
    sent_messages: int = 0
    sent_bytes: int = 0
    closed: bool = False
    # Frames waiting for this client's frame on a worker (order is kept per client).
    pending: deque[str | bytes] = field(default_factory=deque)
    pending_bytes: int = 0
    converting: bool = False
    capacity: asyncio.Event = field(default_factory=asyncio.Event)


@dataclass(frozen=True)
class ClientStats:
    id: int
    peer: str
    queue_depth: int
    queued_bytes: int
    sent_messages: int
    sent_bytes: int
    received: int
    rejected: int
    dropped: int
    subscriptions: int
    lost: int = 0
    status_suppressed: int = 0
    pending_publishes: int = 0


@dataclass
class BridgeTotals:
    """Counters since the bridge started, departed clients included (diagnostics must not forget)."""

    connections: int = 0
    received: int = 0
    rejected: int = 0
    sent_messages: int = 0
    sent_bytes: int = 0
    dropped: int = 0  # by the bridge: a client read too slowly (video replacements included)
    lost_upstream: int = 0  # before the bridge: ROS history overwritten (publication sequence gaps)
    status_suppressed: int = 0  # refusals coalesced into a `suppressed` summary
    internal_errors: int = 0

    def add_session(self, session: ClientSession) -> None:
        self.received += session.received
        self.rejected += session.rejected
        self.sent_messages += session.sent_messages
        self.sent_bytes += session.sent_bytes
        self.dropped += sum(session.queue.dropped.values())
        self.status_suppressed += session.queue.control_overflow


class BridgeCore:
    def __init__(
        self,
        params: BridgeParams,
        allow: AllowLists,
        graph: RosGraph,
        namespace: str = "/",
        clock: Callable[[], float] = time.monotonic,
        executor: Executor | None = None,
    ) -> None:
        self.params = params
        self.graph = graph
        self.namespace = namespace
        self._clock = clock
        self._subscribable = {resolve_topic(rule.topic, namespace): rule for rule in allow.subscribe}
        self._publishable = {resolve_topic(rule.topic, namespace): rule for rule in allow.publish}
        self._sessions: dict[int, ClientSession] = {}
        self._subscribers: dict[str, list[ClientSession]] = {}
        self._ids = itertools.count(1)
        self._last_state: dict[str, str] = {}  # state topics: a new subscriber gets the current value
        self._executor = executor
        self._owns_executor = executor is None
        self._stopped = False
        self._log_limiter = LogLimiter(params.refusal_logs_per_s, clock=clock)
        self._closed_totals = BridgeTotals()
        self.delivered = 0
        self.lost_upstream: dict[str, int] = {}

    # --- connections -------------------------------------------------------------------------

    @property
    def sessions(self) -> list[ClientSession]:
        return list(self._sessions.values())

    def open_session(self, peer: str) -> ClientSession:
        session = ClientSession(
            peer,
            SendQueue(
                self.params.send_queue_messages, self.params.send_queue_bytes, self.params.status_queue_bytes
            ),
            TokenBucket(self.params.rate_limit_per_s, self.params.rate_burst, self._clock),
            id=next(self._ids),
        )
        session.capacity.set()
        self._sessions[session.id] = session
        self._closed_totals.connections += 1
        log.info("client %d connected from %s", session.id, peer)
        return session

    def close_session(self, session: ClientSession) -> None:
        if session.closed:
            return
        session.closed = True
        for full_topic in list(session.subscriptions):
            self._drop_subscription(session, full_topic)
        self._sessions.pop(session.id, None)
        # Frames already accepted (a last command before hanging up) are still published; what is
        # counted from here on belongs to the totals.
        self._closed_totals.add_session(session)
        log.info("client %d (%s) disconnected", session.id, session.peer)

    def shutdown(self) -> None:
        """Stop the conversion workers (frames still waiting are not published)."""
        self._stopped = True
        if self._executor is not None and self._owns_executor:
            self._executor.shutdown(wait=False, cancel_futures=True)
            self._executor = None

    # --- inbound -----------------------------------------------------------------------------

    def handle_frame(self, session: ClientSession, frame: str | bytes) -> None:
        """Process one inbound frame; every refusal becomes a status error to this client only."""
        session.received += 1
        size = utf8_size(frame)
        if size > self.params.max_message_bytes:
            self._refuse(
                session,
                f"message of {size} bytes exceeds the limit of {self.params.max_message_bytes}",
                "too_large",
            )
            return
        if not session.limiter.allow():
            self._refuse(
                session, f"rate limit of {self.params.rate_limit_per_s:g} requests/s exceeded", "rate_limited"
            )
            return
        if session.converting or session.pending:
            session.pending.append(frame)  # behind this client's frame on a worker: keep the order
            session.pending_bytes += size
            self._update_capacity(session)
        elif size <= self.params.inline_convert_bytes:
            self._process_inline(session, frame)
        else:
            self._offload(session, frame)

    def accepts_more(self, session: ClientSession) -> bool:
        """False while this client's waiting frames are at their bound: stop reading from it."""
        return (
            len(session.pending) < self.params.pending_publish_messages
            and session.pending_bytes < self.params.pending_publish_bytes
        )

    async def wait_accepts_more(self, session: ClientSession) -> None:
        while not self.accepts_more(session):
            session.capacity.clear()
            await session.capacity.wait()

    def _update_capacity(self, session: ClientSession) -> None:
        if self.accepts_more(session):
            session.capacity.set()
        else:
            session.capacity.clear()

    def _process_inline(self, session: ClientSession, frame: str | bytes) -> None:
        try:
            request, converted = self._prepare(frame)
        except Exception as error:  # noqa: BLE001 - every outcome becomes a reply, never a dead connection
            self._refuse_error(session, error)
            return
        self._apply_or_refuse(session, request, converted)

    def _offload(self, session: ClientSession, frame: str | bytes) -> None:
        if self._stopped:  # no new workers once shut down
            self._refuse(session, STOPPING, "internal_error")
            return
        if self._executor is None:
            self._executor = ThreadPoolExecutor(
                self.params.convert_threads, thread_name_prefix="bridge-convert"
            )
        loop = asyncio.get_running_loop()

        def back_to_loop(done: Future[tuple[Request, Any]]) -> None:
            try:
                loop.call_soon_threadsafe(self._offload_done, session, done)
            except RuntimeError:  # the loop is closed: the bridge stopped, nobody is left to answer
                pass

        session.converting = True
        self._executor.submit(self._prepare, frame).add_done_callback(back_to_loop)

    def _offload_done(self, session: ClientSession, future: Future[tuple[Request, Any]]) -> None:
        session.converting = False
        # The worker's exception is taken, never re-raised here: raised in this frame, its traceback
        # would hold this frame, whose `future` holds the exception. Such a cycle waits for the
        # cyclic GC, and with it the client's frame (80 refused 1 MB requests held 50 MB).
        if future.cancelled():
            self._refuse(session, STOPPING, "internal_error")
        elif (error := future.exception()) is not None:
            self._refuse_error(session, error)
        else:
            self._apply_or_refuse(session, *future.result())
        self._pump(session)

    def _pump(self, session: ClientSession) -> None:
        """Run this client's waiting frames in order, until one has to go to a worker."""
        while session.pending and not session.converting:
            frame = session.pending.popleft()
            size = utf8_size(frame)
            session.pending_bytes -= size
            if size <= self.params.inline_convert_bytes:
                self._process_inline(session, frame)
            else:
                self._offload(session, frame)
        self._update_capacity(session)

    def _prepare(self, frame: str | bytes) -> tuple[Request, Any]:
        """Parse and, for a publish, convert. Pure (reads only immutable state): runs on workers too."""
        request = parse_request(frame, self.params.max_json_depth)
        if not isinstance(request, Publish):
            return request, None
        rule, _ = self._publish_rule(request.topic, request.id)
        try:
            return request, self.graph.convert(rule, request.msg)
        except PublishError as error:
            raise _Refusal(
                f"cannot publish on {preview(request.topic)} ({rule.type}): {error}",
                "bad_message",
                request.id,
                request.topic,
            ) from None

    def _apply_or_refuse(self, session: ClientSession, request: Request, converted: Any) -> None:
        try:
            if isinstance(request, Publish):
                self._publish(session, request, converted)  # even if the client hung up meanwhile
            elif not session.closed:  # a subscription for a departed client would leak
                self._dispatch(session, request)
        except Exception as error:  # noqa: BLE001 - every outcome becomes a reply, never a dead task
            self._refuse_error(session, error)

    def _refuse_error(self, session: ClientSession, error: BaseException) -> None:
        if isinstance(error, ProtocolError):
            self._refuse(session, str(error), "bad_request", error.request_id, topic="")
        elif isinstance(error, _Refusal):
            self._refuse(session, error.message, error.code, error.request_id, error.topic, error.level)
        else:  # a bug: say so (once per burst in the log), keep the connection and the bridge alive
            self._closed_totals.internal_errors += 1
            log.error("client %d: internal error handling a request", session.id, exc_info=error)
            self._refuse(session, f"internal error: {type(error).__name__}", "internal_error")

    def _dispatch(self, session: ClientSession, request: Request) -> None:
        if isinstance(request, Subscribe):
            self._subscribe(session, request)
        elif isinstance(request, Unsubscribe):
            full = self._resolve(request.topic, request.id)
            if full not in session.subscriptions:
                raise _Refusal(
                    f"not subscribed to {preview(request.topic)}",
                    "not_subscribed",
                    request.id,
                    request.topic,
                    level="warning",
                )
            self._drop_subscription(session, full)
        elif isinstance(request, Advertise):
            rule, full = self._publish_rule(request.topic, request.id)
            if request.type != rule.type:
                raise _Refusal(
                    f"topic {preview(request.topic)} has type {rule.type}, not {request.type}",
                    "wrong_type",
                    request.id,
                    request.topic,
                )
            self.graph.advertise(rule, full)
            session.advertised.add(full)
        elif isinstance(request, Unadvertise):
            session.advertised.discard(self._resolve(request.topic, request.id))
        else:
            raise TypeError(f"unexpected request {type(request).__name__}")  # publishes go through _apply

    def _subscribe(self, session: ClientSession, request: Subscribe) -> None:
        full = self._resolve(request.topic, request.id)
        rule = self._subscribable.get(full)
        if rule is None:
            raise _Refusal(
                f"topic {preview(request.topic)} is not in the subscribe allow-list",
                "not_allowed",
                request.id,
                request.topic,
            )
        if request.type is not None and request.type != rule.type:
            raise _Refusal(
                f"topic {preview(request.topic)} has type {rule.type}, not {request.type}",
                "wrong_type",
                request.id,
                request.topic,
            )
        limit = self.params.send_queue_messages
        queue_length = min(request.queue_length, limit) if request.queue_length else limit
        first = full not in session.subscriptions
        session.subscriptions[full] = _Subscription(
            request.topic, rule, request.throttle_rate_ms / 1000.0, queue_length
        )
        if first:
            last = self._last_state.get(full)
            if last is not None:
                session.queue.put(encode_publish(request.topic, last), full, False, queue_length)
            subscribers = self._subscribers.setdefault(full, [])
            subscribers.append(session)
            if len(subscribers) == 1:
                self.graph.subscribe(rule, full)

    def _publish(self, session: ClientSession, request: Publish, message: Any) -> None:
        rule, full = self._publish_rule(request.topic, request.id)
        if full not in session.advertised:
            self.graph.advertise(rule, full)  # rosbridge lets a publish imply the advertise
            session.advertised.add(full)
        try:
            self.graph.publish(rule, full, message)
        except PublishError as error:
            raise _Refusal(
                f"cannot publish on {preview(request.topic)} ({rule.type}): {error}",
                "publish_failed",
                request.id,
                request.topic,
            ) from None

    def _publish_rule(self, topic: str, request_id: RequestId | None) -> tuple[TopicRule, str]:
        full = self._resolve(topic, request_id)
        rule = self._publishable.get(full)
        if rule is None:
            raise _Refusal(
                f"topic {preview(topic)} is not in the publish allow-list", "not_allowed", request_id, topic
            )
        return rule, full

    def _resolve(self, topic: str, request_id: RequestId | None) -> str:
        try:
            return resolve_topic(topic, self.namespace)
        except ValueError as error:
            raise _Refusal(str(error), "bad_topic", request_id, topic) from None

    def _drop_subscription(self, session: ClientSession, full_topic: str) -> None:
        session.subscriptions.pop(full_topic, None)
        subscribers = self._subscribers.get(full_topic, [])
        if session in subscribers:
            subscribers.remove(session)
        if not subscribers and full_topic in self._subscribers:
            del self._subscribers[full_topic]
            self.graph.unsubscribe(full_topic)

    def _refuse(
        self,
        session: ClientSession,
        message: str,
        code: str,
        request_id: RequestId | None = None,
        topic: str = "",
        level: str = "error",
    ) -> None:
        if session.closed:
            self._closed_totals.rejected += 1  # its counters were already added to the totals
        else:
            session.rejected += 1
        if len(message) > MAX_STATUS_MESSAGE_CHARS:
            message = message[:MAX_STATUS_MESSAGE_CHARS] + "…"
        held = self._log_limiter.allow()  # refusals are client-driven: so would be the log's size
        if held is not None:
            log.warning(
                "client %d (%s) refused [%s] (%d refusals so far%s): %s",
                session.id,
                session.peer,
                code,
                session.rejected,
                f"; {held} refusal log line(s) suppressed" if held else "",
                message,
            )
        status = Status("warning" if level == "warning" else "error", message, request_id, code, topic)
        session.queue.put_control(encode_status(status), code)

    # --- outbound ----------------------------------------------------------------------------

    def deliver(self, full_topic: str, msg_json: str, current: bool = True) -> None:
        """A ROS message arrived (already JSON): queue it for every subscriber of that exact topic.
        `current` is False for a message taken after its publisher left: it is passed on but not
        remembered as the topic's state."""
        now = self._clock()
        rule = self._subscribable.get(full_topic)
        if current and rule is not None and rule.topic_class == "state":
            self._last_state[full_topic] = msg_json
        for session in self._subscribers.get(full_topic, ()):
            sub = session.subscriptions[full_topic]
            if sub.throttle_s and now - sub.last_sent < sub.throttle_s:
                sub.throttled += 1  # the client asked for at most one message per throttle_rate
                continue
            sub.last_sent = now
            session.queue.put(
                encode_publish(sub.client_topic, msg_json),
                full_topic,
                sub.rule.drops_oldest,
                sub.queue_length,
            )
        self.delivered += 1

    def report_lost(self, full_topic: str, count: int) -> None:
        """`count` messages of `full_topic` never reached the bridge (seen as sequence gaps in ROS)."""
        self.lost_upstream[full_topic] = self.lost_upstream.get(full_topic, 0) + count
        for session in self._subscribers.get(full_topic, ()):
            session.queue.count_lost(full_topic, count)

    def forget_state(self, full_topic: str) -> None:
        """The topic's last publisher left: its cached value is no longer the current state."""
        if self._last_state.pop(full_topic, None) is None:
            return
        log.info("forgot the last value of %s: it has no publisher any more", full_topic)
        for session in self._subscribers.get(full_topic, ()):
            client_topic = session.subscriptions[full_topic].client_topic
            status = Status(
                "warning",
                f"{client_topic} has no publisher any more: its last value is not current",
                code="publisher_gone",
                topic=client_topic,
            )
            session.queue.put_control(encode_status(status), "publisher_gone")

    def subscribed_topics(self) -> list[str]:
        return sorted(self._subscribers)

    def totals(self) -> BridgeTotals:
        """Cumulative counters: departed clients plus the connected ones."""
        totals = BridgeTotals(**{f.name: getattr(self._closed_totals, f.name) for f in fields(BridgeTotals)})
        for session in self._sessions.values():
            totals.add_session(session)
        totals.lost_upstream = sum(self.lost_upstream.values())
        return totals

    def stats(self) -> list[ClientStats]:
        return [
            ClientStats(
                s.id,
                s.peer,
                s.queue.depth,
                s.queue.queued_bytes,
                s.sent_messages,
                s.sent_bytes,
                s.received,
                s.rejected,
                sum(s.queue.dropped.values()),
                len(s.subscriptions),
                sum(s.queue.lost.values()),
                s.queue.control_overflow,
                len(s.pending) + int(s.converting),
            )
            for s in self._sessions.values()
        ]


class _Refusal(Exception):
    def __init__(
        self, message: str, code: str, request_id: RequestId | None, topic: str, level: str = "error"
    ) -> None:
        super().__init__(message)
        self.message = message
        self.code = code
        self.request_id = request_id
        self.topic = topic
        self.level = level
