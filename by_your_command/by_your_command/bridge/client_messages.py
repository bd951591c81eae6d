"""What BridgeClient hands to an agent: typed deliveries, a health snapshot, and why it stopped."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from by_your_command.bridge.config import TOPIC_CLASSES, TopicClass
from by_your_command.bridge.protocol import GoalFeedback, GoalResult, ServiceReply

__all__ = [
    "BridgeRefused",
    "BridgeUnavailable",
    "ClientClosed",
    "ClientFailed",
    "ClientHealth",
    "ClientStopped",
    "Delivery",
    "GoalFeedback",
    "GoalResult",
    "Lost",
    "Received",
    "ServiceReply",
    "TooManyCalls",
    "zero_per_class",
]

# The order receive() serves the classes in: commands first, then state, then the data streams.
# Audio, text and video share one lane in arrival order (a frame belongs next to the speech it shows).
DELIVERY_ORDER: tuple[TopicClass, ...] = ("command", "state", "audio", "text", "video")


@dataclass(frozen=True, slots=True)
class Received:
    """One message from the bridge."""

    topic: str  # exactly as the client subscribed it
    topic_class: TopicClass
    msg: dict[str, Any]  # the ROS message as rosbridge JSON (protocol.md "Message encoding")
    received_at: float  # time.monotonic() when it was read from the socket: lets agents see staleness
    superseded: int = 0  # state only: newer values replaced this many older ones of the same key unread


@dataclass(frozen=True, slots=True)
class Lost:
    """Messages of `topic` that will never arrive, in order with what was received around them."""

    topic: str
    topic_class: TopicClass
    count: int | None  # None: unknown (the connection dropped; what the bridge had queued is gone)
    reason: str
    received_at: float


# Calls (protocol.md "Services and actions"): ServiceReply and GoalResult are never dropped and come
# once per call (ok False, code "disconnected", when the connection drops first); GoalFeedback is
# latest-wins per goal id.
Delivery = Received | Lost | ServiceReply | GoalFeedback | GoalResult


@dataclass(frozen=True)
class ClientHealth:
    """A snapshot for the agent runtime and its metrics; every counter is cumulative."""

    running: bool  # False once closed, refused or failed: receive() raises after draining
    connected: bool
    connects: int
    reconnects: int  # connects after the first one
    connection_failures: int  # attempts that failed or connections that ended abnormally
    protocol_errors: int  # malformed frames or fields from the bridge (ignored, logged)
    callback_errors: int  # exceptions raised by on_status (contained, logged)
    internal_errors: int  # unexpected exceptions caught by the supervisor (it went on)
    queued: dict[TopicClass, int]  # deliveries waiting for receive()
    dropped: dict[TopicClass, int]  # replaced here before being read (state and video: latest wins)
    bridge_dropped: dict[TopicClass, int]  # the bridge's `dropped` reports (this client read too slowly)
    unknown_losses: int  # Lost(count=None) events: reconnects with subscriptions that could lose data
    reading_paused: bool  # back-pressure now: the command or audio/text lane is full
    reading_pauses: int  # how often reading paused (the consumer fell behind)
    last_error: str
    outstanding_calls: int = 0  # service calls and goals sent and not yet answered
    feedback_dropped: int = 0  # goal feedback replaced here by newer feedback or the result, unread

    @property
    def errors(self) -> int:
        return self.protocol_errors + self.callback_errors + self.internal_errors


def zero_per_class() -> dict[TopicClass, int]:
    return dict.fromkeys(TOPIC_CLASSES, 0)


class ClientStopped(ConnectionError):
    """The client no longer runs: nothing more will arrive and nothing can be sent."""


class ClientClosed(ClientStopped):
    """close() was called."""


class ClientFailed(ClientStopped):
    """The client's supervisor task ended unexpectedly (the cause is chained)."""


class BridgeUnavailable(ConnectionError):
    """The bridge is not connected right now (the client keeps trying in the background)."""


class TooManyCalls(RuntimeError):
    """More service calls and goals outstanding than ClientOptions.max_outstanding_calls."""


class BridgeRefused(ClientStopped):
    """The bridge refused the handshake (HTTP 401/403): a wrong token does not fix itself."""
