"""The client's receive buffer: one lane per class, served commands first, then state, then data.

- command: FIFO, never dropped (bounded by back-pressure: the client stops reading when full).
- state: latest value wins per topic, or per (topic, key field) where a topic names one
  (`playback_status` per `stream_id`, so a reply's last status is not replaced by the next
  reply's). A pending `finished`/`interrupted` value is never replaced by a non-terminal one.
- audio and text: one FIFO, never dropped (back-pressure), so an utterance's chunks and its
  end marker stay in order with typed text.
- video: latest frame per topic, served in arrival order with audio and text.
Loss events (`Lost`) go to the lane of their class, in order with the messages around them.
Call replies and goal results share the command lane (never dropped); goal feedback is latest-wins
per goal id, served after state, and a goal's pending feedback goes when its result arrives.
"""

from __future__ import annotations

import logging
from collections import OrderedDict, deque
from dataclasses import dataclass, replace

from by_your_command.bridge.client_messages import (
    Delivery,
    GoalFeedback,
    GoalResult,
    Lost,
    Received,
    ServiceReply,
    zero_per_class,
)
from by_your_command.bridge.client_topics import base_name
from by_your_command.bridge.config import TopicClass
from by_your_command.bridge.protocol import RequestId

log = logging.getLogger(__name__)

_LOSS_KEY = object()  # state-lane key of a topic's pending loss report (merged, never replaced)


@dataclass(frozen=True)
class InboxLimits:
    stream_messages: int = 1000  # audio + text waiting for receive() before reading pauses
    command_messages: int = 256  # commands waiting before reading pauses
    state_keys_per_topic: int = 32  # e.g. playback_status stream_ids pending at once
    # (topic base name, message field): state values are latest-wins per value of that field.
    state_key_fields: tuple[tuple[str, str], ...] = (("playback_status", "stream_id"),)

    def __post_init__(self) -> None:
        for name in ("stream_messages", "command_messages", "state_keys_per_topic"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")


def is_terminal(msg: dict[str, object]) -> bool:
    """A transition that must reach the agent even if newer values follow (PlaybackStatus)."""
    return msg.get("finished") is True or msg.get("interrupted") is True


class Inbox:
    def __init__(self, limits: InboxLimits | None = None) -> None:
        self.limits = limits or InboxLimits()
        self._key_fields = dict(self.limits.state_key_fields)
        self._command: deque[Delivery] = deque()
        self._state: OrderedDict[tuple[str, object], Delivery] = OrderedDict()
        self._state_keys: dict[str, int] = {}
        self._stream: deque[tuple[int, Delivery]] = deque()  # (arrival number, delivery)
        self._video: OrderedDict[str, tuple[int, Delivery]] = OrderedDict()
        self._feedback: OrderedDict[RequestId, GoalFeedback] = OrderedDict()
        self._arrivals = 0
        self._queued = zero_per_class()
        self.dropped = zero_per_class()  # replaced before being read (state, video)
        self.feedback_dropped = 0  # goal feedback replaced by newer feedback or by the result

    def put_reply(self, item: ServiceReply | GoalResult) -> None:
        """A call's reply or a goal's result: never dropped (bounded by the calls outstanding)."""
        self._command.append(item)
        if isinstance(item, GoalResult) and self._feedback.pop(item.id, None) is not None:
            self.feedback_dropped += 1  # the result says more than a progress report would

    def put_feedback(self, item: GoalFeedback) -> None:
        if self._feedback.pop(item.id, None) is not None:
            self.feedback_dropped += 1
        self._feedback[item.id] = item

    # --- in ---------------------------------------------------------------------------------

    def put(self, item: Received) -> None:
        topic_class = item.topic_class
        self._queued[topic_class] += 1
        if topic_class == "audio" or topic_class == "text":
            self._arrivals += 1
            self._stream.append((self._arrivals, item))
        elif topic_class == "command":
            self._command.append(item)
        elif topic_class == "state":
            self._put_state(item)
        else:
            self._put_video(item)

    def put_lost(self, lost: Lost) -> None:
        topic_class = lost.topic_class
        if topic_class == "command":
            self._command.append(lost)
        elif topic_class == "state":
            key = (lost.topic, _LOSS_KEY)
            pending = self._state.get(key)
            if isinstance(pending, Lost):
                total = None if pending.count is None or lost.count is None else pending.count + lost.count
                lost = replace(lost, count=total)
            else:
                self._queued[topic_class] += 1
            self._state[key] = lost
            self._state.move_to_end(key)
            return
        else:  # audio, text, video: in order with the data around the gap
            self._arrivals += 1
            self._stream.append((self._arrivals, lost))
        self._queued[topic_class] += 1

    def _put_state(self, item: Received) -> None:
        field = self._key_fields.get(base_name(item.topic))
        sub_key = item.msg.get(field) if field else None
        key = (item.topic, sub_key if isinstance(sub_key, (str, int)) else None)
        pending = self._state.get(key)
        if isinstance(pending, Received):
            self._queued["state"] -= 1  # put() counted the new value; one of the two goes
            self.dropped["state"] += 1
            if is_terminal(pending.msg) and not is_terminal(item.msg):
                # The reply already finished or was cut: a later non-terminal echo adds nothing.
                self._state[key] = replace(pending, superseded=pending.superseded + 1)
                return
            item = replace(item, superseded=pending.superseded + 1)
        else:
            if self._state_keys.get(item.topic, 0) >= self.limits.state_keys_per_topic:
                self._evict_oldest_key(item.topic)
            self._state_keys[item.topic] = self._state_keys.get(item.topic, 0) + 1
        self._state[key] = item
        self._state.move_to_end(key)

    def _evict_oldest_key(self, topic: str) -> None:
        victim = next(k for k, v in self._state.items() if k[0] == topic and isinstance(v, Received))
        del self._state[victim]
        self._state_keys[topic] -= 1
        self._queued["state"] -= 1
        self.dropped["state"] += 1
        log.warning(
            "%s: more than %d keys pending; dropped the oldest", topic, self.limits.state_keys_per_topic
        )

    def _put_video(self, item: Received) -> None:
        self._arrivals += 1
        if self._video.pop(item.topic, None) is not None:
            self._queued[item.topic_class] -= 1
            self.dropped[item.topic_class] += 1
        self._video[item.topic] = (self._arrivals, item)

    # --- out --------------------------------------------------------------------------------

    def pop(self) -> Delivery | None:
        if self._command:
            item = self._command.popleft()
        elif self._state:
            key, item = self._state.popitem(last=False)
            if key[1] is not _LOSS_KEY:
                self._state_keys[key[0]] -= 1
        elif self._feedback:
            return self._feedback.popitem(last=False)[1]
        elif self._video and (not self._stream or next(iter(self._video.values()))[0] < self._stream[0][0]):
            item = self._video.popitem(last=False)[1][1]
        elif self._stream:
            item = self._stream.popleft()[1]
        else:
            return None
        if isinstance(item, (Received, Lost)):
            self._queued[item.topic_class] -= 1
        return item

    @property
    def full(self) -> bool:
        """Stop reading the socket: the never-dropped lanes are at their bound."""
        return (
            len(self._stream) >= self.limits.stream_messages
            or len(self._command) >= self.limits.command_messages
        )

    def queued(self) -> dict[TopicClass, int]:
        return dict(self._queued)

    def __len__(self) -> int:
        return (
            len(self._command) + len(self._state) + len(self._stream) + len(self._video) + len(self._feedback)
        )
