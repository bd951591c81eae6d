"""The bridge's protocol logic, independent of sockets and of ROS.

`BridgeCore` validates every request against the allow-lists, keeps per-client state and routes
ROS messages (already JSON-encoded once) into each subscriber's bounded send queue. It talks to
ROS only through the small `RosGraph` port, so tests drive it with a fake graph.
All methods run on the asyncio loop's thread.
"""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from by_your_command.bridge.config import AllowLists, BridgeParams, TopicRule
from by_your_command.bridge.flow import SendQueue, TokenBucket
from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.protocol import (
    Advertise,
    ProtocolError,
    Publish,
    Request,
    Status,
    Subscribe,
    Unadvertise,
    Unsubscribe,
    encode_publish,
    encode_status,
    parse_request,
)

log = logging.getLogger(__name__)


class PublishError(ValueError):
    """A client message that cannot become a ROS message (wrong fields or types)."""


class RosGraph(Protocol):
    """What the core needs from ROS. Implementations may be called only from the loop thread."""

    def subscribe(self, rule: TopicRule, full_topic: str) -> None:
        """Start delivering `full_topic` to `BridgeCore.deliver` (idempotent).

        Topics of class `state` should be delivered even without subscribers: the core keeps
        their last value for clients that subscribe later.
        """

    def unsubscribe(self, full_topic: str) -> None:
        """No client wants `full_topic` any more."""

    def advertise(self, rule: TopicRule, full_topic: str) -> None:
        """Make sure a publisher exists (idempotent)."""

    def publish(self, rule: TopicRule, full_topic: str, msg: dict[str, Any]) -> None:
        """Convert and publish; raise PublishError with a client-facing message on bad content."""


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


class BridgeCore:
    def __init__(
        self,
        params: BridgeParams,
        allow: AllowLists,
        graph: RosGraph,
        namespace: str = "/",
        clock: Callable[[], float] = time.monotonic,
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
        self.delivered = 0

    # --- connections -------------------------------------------------------------------------

    @property
    def sessions(self) -> list[ClientSession]:
        return list(self._sessions.values())

    def open_session(self, peer: str) -> ClientSession:
        session = ClientSession(
            peer,
            SendQueue(self.params.send_queue_messages, self.params.send_queue_bytes),
            TokenBucket(self.params.rate_limit_per_s, self.params.rate_burst, self._clock),
            id=next(self._ids),
        )
        self._sessions[session.id] = session
        log.info("client %d connected from %s", session.id, peer)
        return session

    def close_session(self, session: ClientSession) -> None:
        session.closed = True
        for full_topic in list(session.subscriptions):
            self._drop_subscription(session, full_topic)
        self._sessions.pop(session.id, None)
        log.info("client %d (%s) disconnected", session.id, session.peer)

    # --- inbound -----------------------------------------------------------------------------

    def handle_frame(self, session: ClientSession, frame: str | bytes) -> None:
        """Process one inbound frame; every refusal becomes a status error to this client only."""
        session.received += 1
        if len(frame) > self.params.max_message_bytes:
            self._refuse(
                session,
                f"message of {len(frame)} bytes exceeds the limit of {self.params.max_message_bytes}",
                "too_large",
            )
            return
        if not session.limiter.allow():
            self._refuse(
                session, f"rate limit of {self.params.rate_limit_per_s:g} requests/s exceeded", "rate_limited"
            )
            return
        try:
            request = parse_request(frame)
            self._dispatch(session, request)
        except ProtocolError as error:
            self._refuse(session, str(error), "bad_request", error.request_id, topic="")
        except _Refusal as refusal:
            self._refuse(
                session, refusal.message, refusal.code, refusal.request_id, refusal.topic, refusal.level
            )

    def _dispatch(self, session: ClientSession, request: Request) -> None:
        if isinstance(request, Subscribe):
            self._subscribe(session, request)
        elif isinstance(request, Unsubscribe):
            full = self._resolve(request.topic, request.id)
            if full not in session.subscriptions:
                raise _Refusal(
                    f"not subscribed to {request.topic!r}",
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
                    f"topic {request.topic!r} has type {rule.type}, not {request.type}",
                    "wrong_type",
                    request.id,
                    request.topic,
                )
            self.graph.advertise(rule, full)
            session.advertised.add(full)
        elif isinstance(request, Unadvertise):
            session.advertised.discard(self._resolve(request.topic, request.id))
        else:
            self._publish(session, request)

    def _subscribe(self, session: ClientSession, request: Subscribe) -> None:
        full = self._resolve(request.topic, request.id)
        rule = self._subscribable.get(full)
        if rule is None:
            raise _Refusal(
                f"topic {request.topic!r} ({full}) is not in the subscribe allow-list",
                "not_allowed",
                request.id,
                request.topic,
            )
        if request.type is not None and request.type != rule.type:
            raise _Refusal(
                f"topic {request.topic!r} has type {rule.type}, not {request.type}",
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

    def _publish(self, session: ClientSession, request: Publish) -> None:
        rule, full = self._publish_rule(request.topic, request.id)
        if full not in session.advertised:
            self.graph.advertise(rule, full)  # rosbridge lets a publish imply the advertise
            session.advertised.add(full)
        try:
            self.graph.publish(rule, full, request.msg)
        except PublishError as error:
            raise _Refusal(
                f"cannot publish on {request.topic!r} ({rule.type}): {error}",
                "bad_message",
                request.id,
                request.topic,
            ) from None

    def _publish_rule(self, topic: str, request_id: str | None) -> tuple[TopicRule, str]:
        full = self._resolve(topic, request_id)
        rule = self._publishable.get(full)
        if rule is None:
            raise _Refusal(
                f"topic {topic!r} ({full}) is not in the publish allow-list", "not_allowed", request_id, topic
            )
        return rule, full

    def _resolve(self, topic: str, request_id: str | None) -> str:
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
        request_id: str | None = None,
        topic: str = "",
        level: str = "error",
    ) -> None:
        session.rejected += 1
        if session.rejected <= 10 or session.rejected % 100 == 0:  # a flood must not flood the log
            log.warning(
                "client %d (%s) refused [%s] (%d refusals so far): %s",
                session.id,
                session.peer,
                code,
                session.rejected,
                message,
            )
        status = Status("warning" if level == "warning" else "error", message, request_id, code, topic)
        session.queue.put_control(encode_status(status))

    # --- outbound ----------------------------------------------------------------------------

    def deliver(self, full_topic: str, msg_json: str) -> None:
        """A ROS message arrived (already JSON): queue it for every subscriber of that exact topic."""
        now = self._clock()
        rule = self._subscribable.get(full_topic)
        if rule is not None and rule.topic_class == "state":
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

    def subscribed_topics(self) -> list[str]:
        return sorted(self._subscribers)

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
            )
            for s in self._sessions.values()
        ]


class _Refusal(Exception):
    def __init__(
        self, message: str, code: str, request_id: str | None, topic: str, level: str = "error"
    ) -> None:
        super().__init__(message)
        self.message = message
        self.code = code
        self.request_id = request_id
        self.topic = topic
        self.level = level
