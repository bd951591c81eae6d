"""The bridge's protocol logic, independent of sockets and of ROS.

`BridgeCore` validates every request against the allow-lists, keeps per-client state and routes
ROS messages (already JSON-encoded once) into each subscriber's bounded send queue. It talks to
ROS only through the small `RosGraph` port, so tests drive it with a fake graph.
Service calls and action goals go through the same port; their outcomes come back as callbacks
and are queued for the client that asked (never dropped; the number a client may have
outstanding is bounded). Goals of a client that leaves are cancelled: nobody is left to stop them.
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
from typing import Any, Literal, Protocol

from by_your_command.bridge.calls import (
    GOAL_ABORTED,
    GOAL_CANCELED,
    GOAL_SUCCEEDED,
    GOAL_UNKNOWN,
    ActionRule,
    CallOutcome,
    ServiceRule,
)
from by_your_command.bridge.config import AllowLists, BridgeParams, ConfigError, TopicRule
from by_your_command.bridge.flow import LogLimiter, SendQueue, TokenBucket
from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.protocol import (
    Advertise,
    CallService,
    CancelActionGoal,
    ProtocolError,
    Publish,
    Request,
    RequestId,
    SendActionGoal,
    Status,
    Subscribe,
    Unadvertise,
    Unsubscribe,
    encode_action_failure,
    encode_action_feedback,
    encode_action_result,
    encode_publish,
    encode_service_failure,
    encode_service_response,
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

    def convert_call(self, type_name: str, part: Literal["request", "goal"], args: dict[str, Any]) -> Any:
        """JSON args → the service Request / action Goal message of `type_name`; raise PublishError
        (client-facing text) on bad content. May run on worker threads, like `convert`."""

    def call_service(
        self,
        rule: ServiceRule,
        full_name: str,
        request: Any,
        timeout_s: float,
        done: Callable[[CallOutcome], None],
    ) -> None:
        """Call the service; `done` exactly once, on the loop thread (response, failure or timeout)."""

    def send_goal(
        self,
        rule: ActionRule,
        full_name: str,
        goal: Any,
        token: int,
        feedback: Callable[[str], None],
        done: Callable[[CallOutcome], None],
    ) -> None:
        """Send the goal; `feedback` with each feedback's fields as JSON object text, `done` exactly
        once when it ends (result, rejection, no server...), both on the loop thread."""

    def cancel_goal(self, token: int) -> None:
        """Cancel the goal sent with `token` (idempotent); its `done` still comes once."""


@dataclass
class _Subscription:
    client_topic: str  # the name as the client wrote it: frames carry it back unchanged
    rule: TopicRule
    throttle_s: float
    queue_length: int
    last_sent: float = float("-inf")
    throttled: int = 0


@dataclass
class _Goal:
    token: int  # the core's handle for the graph (client ids are only unique per client)
    session: ClientSession
    request_id: RequestId
    action: str  # as the client wrote it: frames carry it back unchanged
    full_name: str
    feedback: bool
    cancel_reason: str = ""

    @property
    def key(self) -> str:
        """Its feedback's key in the client's send queue (latest wins per goal)."""
        return f"goal feedback {self.token}"


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
    pending_calls: int = 0  # service calls awaiting their outcome
    goals: dict[RequestId, _Goal] = field(default_factory=dict)  # active goals by the client's id
    service_calls: int = 0
    goals_sent: int = 0


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
    pending_calls: int = 0
    active_goals: int = 0
    service_calls: int = 0
    goals_sent: int = 0
    feedback_dropped: int = 0


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
    service_calls: int = 0  # calls passed to ROS (refused ones are only in `rejected`)
    service_failures: int = 0  # of those: no server, timeout, failed in ROS
    goals_sent: int = 0
    goals_active: int = 0  # now, not cumulative
    goals_succeeded: int = 0
    goals_failed: int = 0  # rejected, aborted, no server, timeout...
    goals_cancelled: int = 0
    feedback_dropped: int = 0  # latest-wins: replaced by newer feedback or the result, or no room
    replies_discarded: int = 0  # outcomes of calls and goals whose client had left

    def add_session(self, session: ClientSession) -> None:
        # Call and goal counters are counted by the core as they happen (outcomes may come after
        # the client left), except feedback drops, which happen in the client's queue.
        self.received += session.received
        self.rejected += session.rejected
        self.sent_messages += session.sent_messages
        self.sent_bytes += session.sent_bytes
        self.dropped += sum(session.queue.dropped.values())
        self.status_suppressed += session.queue.control_overflow
        self.feedback_dropped += session.queue.feedback_dropped


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
        self._services: dict[str, ServiceRule] = _by_full_name(allow.services, namespace, "services")
        self._actions: dict[str, ActionRule] = _by_full_name(allow.actions, namespace, "actions")
        self._goals: dict[int, _Goal] = {}  # every active goal, by token
        self._tokens = itertools.count(1)
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
        for goal in list(session.goals.values()):  # nobody is left to stop them
            self._cancel(goal, "the client disconnected")
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
        """Parse and, for a publish, a call or a goal, convert. Pure (reads only immutable state):
        runs on workers too."""
        request = parse_request(frame, self.params.max_json_depth)
        if isinstance(request, (CallService, SendActionGoal)):
            return request, self._convert_call(request)
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
            elif not session.closed:  # a subscription, call or goal for a departed client would leak
                self._dispatch(session, request, converted)
        except Exception as error:  # noqa: BLE001 - every outcome becomes a reply, never a dead task
            self._refuse_error(session, error, request)

    def _refuse_error(
        self, session: ClientSession, error: BaseException, request: Request | None = None
    ) -> None:
        if isinstance(error, ProtocolError):
            call = None
            if error.op in _ANSWERED_OPS and error.request_id is not None and error.target:
                call = _CallRef(error.op, error.target, error.request_id)
            self._refuse(session, str(error), "bad_request", error.request_id, call=call)
        elif isinstance(error, _Refusal):
            self._refuse(
                session, error.message, error.code, error.request_id, error.topic, error.level, error.call
            )
        else:  # a bug: say so (once per burst in the log), keep the connection and the bridge alive
            self._closed_totals.internal_errors += 1
            log.error("client %d: internal error handling a request", session.id, exc_info=error)
            call = _call_ref(request) if isinstance(request, (CallService, SendActionGoal)) else None
            request_id = None if call is None else call.request_id
            self._refuse(
                session, f"internal error: {type(error).__name__}", "internal_error", request_id, call=call
            )

    def _dispatch(self, session: ClientSession, request: Request, converted: Any) -> None:
        if isinstance(request, CallService):
            self._call_service(session, request, converted)
        elif isinstance(request, SendActionGoal):
            self._send_goal(session, request, converted)
        elif isinstance(request, CancelActionGoal):
            self._cancel_by_client(session, request)
        elif isinstance(request, Subscribe):
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
        call: _CallRef | None = None,
    ) -> None:
        """A status to this client only. For a refused call or goal (`call`), its failing reply follows
        in the same bounded lane: clients such as roslibpy only see a call fail through it."""
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
        if call is not None:
            answer_code = "bad_args" if code == "bad_request" else code
            session.queue.put_control(_failure_frame(call, message, answer_code), code)

    # --- service calls and action goals ------------------------------------------------------

    def _convert_call(self, request: CallService | SendActionGoal) -> Any:
        """Allow-list, type and content checks of a call or goal; runs on workers for large ones."""
        if isinstance(request, CallService):
            rule: ServiceRule | ActionRule = self._service_rule(request)[0]
            what = f"service {preview(request.service)}"
        else:
            rule = self._action_rule(request)[0]
            what = f"action {preview(request.action)}"
        try:
            return self.graph.convert_call(
                rule.type, "request" if isinstance(request, CallService) else "goal", request.args
            )
        except PublishError as error:
            raise _Refusal(
                f"bad arguments for {what} ({rule.type}): {error}",
                "bad_args",
                request.id,
                "",
                call=_call_ref(request),
            ) from None

    def _service_rule(self, request: CallService) -> tuple[ServiceRule, str]:
        full = self._resolve_call(request.service, request)
        rule = self._services.get(full)
        if rule is None:
            raise _Refusal(
                f"service {preview(request.service)} is not in the services allow-list",
                "not_allowed",
                request.id,
                "",
                call=_call_ref(request),
            )
        if request.type is not None and request.type != rule.type:
            raise _Refusal(
                f"service {preview(request.service)} has type {rule.type}, not {request.type}",
                "wrong_type",
                request.id,
                "",
                call=_call_ref(request),
            )
        return rule, full

    def _action_rule(self, request: SendActionGoal) -> tuple[ActionRule, str]:
        full = self._resolve_call(request.action, request)
        rule = self._actions.get(full)
        if rule is None:
            raise _Refusal(
                f"action {preview(request.action)} is not in the actions allow-list",
                "not_allowed",
                request.id,
                "",
                call=_call_ref(request),
            )
        if request.action_type != rule.type:
            raise _Refusal(
                f"action {preview(request.action)} has type {rule.type}, not {request.action_type}",
                "wrong_type",
                request.id,
                "",
                call=_call_ref(request),
            )
        return rule, full

    def _resolve_call(self, name: str, request: CallService | SendActionGoal | CancelActionGoal) -> str:
        try:
            return resolve_topic(name, self.namespace)
        except ValueError as error:
            call = None if isinstance(request, CancelActionGoal) else _call_ref(request)
            raise _Refusal(str(error), "bad_request", request.id, "", call=call) from None

    def _call_service(self, session: ClientSession, request: CallService, message: Any) -> None:
        rule, full = self._service_rule(request)
        if session.pending_calls >= self.params.max_pending_calls:
            raise _Refusal(
                f"already {session.pending_calls} service calls awaiting their response "
                f"(max_pending_calls {self.params.max_pending_calls})",
                "too_many",
                request.id,
                "",
                call=_call_ref(request),
            )
        timeout = rule.timeout_s if request.timeout_s is None else min(rule.timeout_s, request.timeout_s)
        finished = False

        def done(outcome: CallOutcome) -> None:
            nonlocal finished
            if finished:  # the graph promises once; a second one must not unbalance the count
                log.error("service %s: a second outcome for one call was ignored", full)
                return
            finished = True
            self._service_done(session, request, outcome)

        session.pending_calls += 1
        session.service_calls += 1
        self._closed_totals.service_calls += 1
        try:
            self.graph.call_service(rule, full, message, timeout, done)
        except Exception:
            if not finished:
                finished = True
                session.pending_calls -= 1
            raise

    def _service_done(self, session: ClientSession, request: CallService, outcome: CallOutcome) -> None:
        session.pending_calls -= 1
        if not outcome.ok:
            self._closed_totals.service_failures += 1
        if session.closed:
            self._closed_totals.replies_discarded += 1  # nobody to tell; counted, not sent
            return
        if outcome.ok:
            frame = encode_service_response(request.service, request.id, outcome.values_json)
        else:
            error = outcome.error or "the service call failed"
            frame = encode_service_failure(
                request.service, request.id, error, outcome.code or "internal_error"
            )
        self._put_reply(session, frame, _call_ref(request))

    def _send_goal(self, session: ClientSession, request: SendActionGoal, message: Any) -> None:
        rule, full = self._action_rule(request)
        if request.id in session.goals:
            raise _Refusal(
                f"a goal with id {_id_text(request.id)} is still active: ids must be unique",
                "bad_request",
                request.id,
                "",
                call=_call_ref(request),
            )
        if len(session.goals) >= self.params.max_active_goals:
            raise _Refusal(
                f"already {len(session.goals)} active goals "
                f"(max_active_goals {self.params.max_active_goals})",
                "too_many",
                request.id,
                "",
                call=_call_ref(request),
            )
        goal = _Goal(next(self._tokens), session, request.id, request.action, full, request.feedback)
        session.goals[request.id] = goal  # before send_goal: its `done` may come at once
        self._goals[goal.token] = goal
        session.goals_sent += 1
        self._closed_totals.goals_sent += 1
        try:
            self.graph.send_goal(
                rule,
                full,
                message,
                goal.token,
                lambda values_json: self._goal_feedback(goal, values_json),
                lambda outcome: self._goal_done(goal, outcome),
            )
        except Exception:
            self._forget_goal(goal)
            raise

    def _goal_feedback(self, goal: _Goal, values_json: str) -> None:
        session = goal.session
        if not goal.feedback or session.closed or goal.token not in self._goals:
            return
        session.queue.put_feedback(
            encode_action_feedback(goal.action, goal.request_id, values_json), goal.key
        )

    def _goal_done(self, goal: _Goal, outcome: CallOutcome) -> None:
        if not self._forget_goal(goal):
            log.error("action %s: a second outcome for one goal was ignored", goal.full_name)
            return
        if outcome.ok and outcome.status == GOAL_SUCCEEDED:
            self._closed_totals.goals_succeeded += 1
        elif outcome.status == GOAL_CANCELED or outcome.code == "cancelled":
            self._closed_totals.goals_cancelled += 1
        else:
            self._closed_totals.goals_failed += 1
        session = goal.session
        session.queue.discard_feedback(goal.key)  # never after the result
        if session.closed:
            self._closed_totals.replies_discarded += 1
            return
        if outcome.ok:
            frame = encode_action_result(goal.action, goal.request_id, outcome.status, outcome.values_json)
        else:
            error = outcome.error or "the goal failed"
            if goal.cancel_reason:
                error = f"{error} ({goal.cancel_reason})"
            status = outcome.status
            if status == GOAL_UNKNOWN and outcome.code != "rejected":
                status = GOAL_ABORTED  # only a rejected goal never had a status
            frame = encode_action_failure(
                goal.action, goal.request_id, status, error, outcome.code or "internal_error"
            )
        self._put_reply(session, frame, _CallRef("send_action_goal", goal.action, goal.request_id))

    def _forget_goal(self, goal: _Goal) -> bool:
        """False when it had already ended."""
        if self._goals.pop(goal.token, None) is None:
            return False
        if goal.session.goals.get(goal.request_id) is goal:
            del goal.session.goals[goal.request_id]
        return True

    def _cancel_by_client(self, session: ClientSession, request: CancelActionGoal) -> None:
        full = self._resolve_call(request.action, request)
        goal = session.goals.get(request.id)
        if goal is None or goal.full_name != full:
            raise _Refusal(
                f"no active goal with id {_id_text(request.id)} on {preview(request.action)} "
                "(it ended already, or was never accepted)",
                "not_active",
                request.id,
                "",
                level="warning",
            )
        self._cancel(goal, "cancelled by the client")

    def _cancel(self, goal: _Goal, reason: str) -> bool:
        """Ask the graph to cancel; its `done` reports the end. False if the graph failed."""
        goal.cancel_reason = goal.cancel_reason or reason
        try:
            self.graph.cancel_goal(goal.token)
        except Exception:  # noqa: BLE001 - one failure must not stop the other cancellations
            self._closed_totals.internal_errors += 1
            log.exception("cancelling goal %d on %s failed", goal.token, goal.full_name)
            return False
        return True

    def cancel_all_goals(self, reason: str) -> int:
        """Cancel every active goal of every client (safety_stop); returns how many were asked to stop."""
        goals = list(self._goals.values())
        cancelled = sum(self._cancel(goal, reason) for goal in goals)
        if goals:
            log.warning("cancelling %d active goal(s): %s", len(goals), reason)
        return cancelled

    def _put_reply(self, session: ClientSession, frame: str, call: _CallRef) -> None:
        size = utf8_size(frame)
        if size > self.params.send_queue_bytes:  # never silently lost: the call fails visibly instead
            message = (
                f"the reply of {size} bytes exceeds this client's send queue ({self.params.send_queue_bytes})"
            )
            log.warning("client %d: %s", session.id, message)
            frame = _failure_frame(call, message, "too_large")
        session.queue.put_reply(frame)

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
        totals.goals_active = len(self._goals)
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
                s.pending_calls,
                len(s.goals),
                s.service_calls,
                s.goals_sent,
                s.queue.feedback_dropped,
            )
            for s in self._sessions.values()
        ]


class _Refusal(Exception):
    def __init__(
        self,
        message: str,
        code: str,
        request_id: RequestId | None,
        topic: str,
        level: str = "error",
        call: _CallRef | None = None,  # a refused call or goal: it also gets its failing reply
    ) -> None:
        super().__init__(message)
        self.message = message
        self.code = code
        self.request_id = request_id
        self.topic = topic
        self.level = level
        self.call = call


_ANSWERED_OPS = ("call_service", "send_action_goal")


@dataclass(frozen=True)
class _CallRef:
    """What a failing reply names: the op, the service or action as the client wrote it, the id."""

    op: str
    name: str
    request_id: RequestId


def _call_ref(request: CallService | SendActionGoal) -> _CallRef:
    if isinstance(request, CallService):
        return _CallRef("call_service", request.service, request.id)
    return _CallRef("send_action_goal", request.action, request.id)


def _failure_frame(call: _CallRef, message: str, code: str) -> str:
    if call.op == "call_service":
        return encode_service_failure(call.name, call.request_id, message, code)
    return encode_action_failure(call.name, call.request_id, GOAL_ABORTED, message, code)


def _id_text(request_id: RequestId) -> str:
    return preview(request_id) if isinstance(request_id, str) else str(request_id)


def _by_full_name(rules: tuple[Any, ...], namespace: str, section: str) -> dict[str, Any]:
    """Allow-listed services or actions by resolved name; one name with two types is a config error."""
    found: dict[str, Any] = {}
    for rule in rules:
        full = resolve_topic(rule.name, namespace)
        known = found.setdefault(full, rule)
        if known.type != rule.type:
            raise ConfigError(f"'{section}': {full} is listed with two types, {known.type} and {rule.type}")
    return found
