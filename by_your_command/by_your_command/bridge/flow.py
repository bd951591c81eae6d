"""Flow control: a client's bounded send queue with per-class drop policy, rate and log limiters."""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from by_your_command.bridge.protocol import Status, encode_status, utf8_size


@dataclass
class _Entry:
    text: str
    topic: str
    drops_oldest: bool
    size: int  # bytes of UTF-8


class SendQueue:
    """Frames waiting for one client's socket, bounded in count and bytes.

    When a topic's share or the whole queue is full:
    - drop-oldest topics (video) replace their own oldest queued frame: only fresh frames matter;
    - every other topic drops the *new* message, counts it and owes the client a `status`
      warning with the counts, sent ahead of the next frame (never a silent loss).
    Status frames (refusals) count towards the same byte bound and have their own, smaller one in
    count and bytes: beyond either, further ones are only counted by code and the client gets one
    `suppressed` summary, so a client that floods us with bad requests and never reads cannot grow
    the bridge. Drop and loss reports are one counter per topic, so they need no bound.
    Sizes are bytes of UTF-8, whatever the text holds.
    Call replies (a service's response, a goal's result) have their own lane, served before data
    and never dropped: the core bounds how many calls a client may have outstanding, so their
    number is bounded. Goal feedback is latest-wins per goal, in the data lane (`put_feedback`).
    """

    def __init__(
        self, max_messages: int, max_bytes: int, max_control_bytes: int = 65_536, max_control: int = 64
    ) -> None:
        self.max_messages = max_messages
        self.max_bytes = max_bytes
        self.max_control_bytes = max_control_bytes
        self.max_control = max_control
        self._entries: deque[_Entry] = deque()
        self._control: deque[str] = deque()
        self._control_bytes = 0
        self._replies: deque[str] = deque()
        self._reply_bytes = 0
        self._per_topic: dict[str, int] = {}
        self._bytes = 0
        self._unreported: dict[str, int] = {}
        self._unreported_lost: dict[str, int] = {}
        self._suppressed: dict[str, int] = {}
        self._wakeup = asyncio.Event()
        self.dropped: dict[str, int] = {}  # every drop by topic (video replacements included)
        self.lost: dict[str, int] = {}  # lost before the bridge (DDS), reported to this subscriber
        self.control_overflow = 0  # status replies coalesced into a `suppressed` summary
        self.feedback_dropped = 0  # goal feedback replaced by newer feedback or by the result, or no room

    @property
    def depth(self) -> int:
        return len(self._entries) + len(self._replies)

    @property
    def queued_bytes(self) -> int:
        """Everything waiting for this client, status replies and call replies included."""
        return self._bytes + self._control_bytes + self._reply_bytes

    def put_reply(self, text: str) -> None:
        """A service response or a goal's result: never dropped (their number is bounded by the
        client's outstanding calls). Counts towards the byte bound, so data yields to it."""
        self._replies.append(text)
        self._reply_bytes += utf8_size(text)
        self._wakeup.set()

    def put_feedback(self, text: str, key: str) -> bool:
        """Goal feedback, latest-wins per `key` (one goal): a queued older one is replaced, and the
        new one is dropped when the queue is full. Either way `feedback_dropped` counts it."""
        victim = next((entry for entry in self._entries if entry.topic == key), None)
        if victim is not None:
            self._remove(victim)
            self.feedback_dropped += 1
        size = utf8_size(text)
        if len(self._entries) >= self.max_messages or self.queued_bytes + size > self.max_bytes:
            self.feedback_dropped += 1
            return False
        self._entries.append(_Entry(text, key, True, size))
        self._per_topic[key] = self._per_topic.get(key, 0) + 1
        self._bytes += size
        self._wakeup.set()
        return victim is None

    def discard_feedback(self, key: str) -> None:
        """The goal ended: its queued feedback must not reach the client after the result."""
        victim = next((entry for entry in self._entries if entry.topic == key), None)
        if victim is not None:
            self._remove(victim)
            self.feedback_dropped += 1

    def put(self, text: str, topic: str, drops_oldest: bool, topic_limit: int) -> bool:
        """Queue a frame; False when it (or an older one of the same topic) had to be dropped."""
        size = utf8_size(text)
        full = (
            self._per_topic.get(topic, 0) >= topic_limit
            or len(self._entries) >= self.max_messages
            or self.queued_bytes + size > self.max_bytes
        )
        if full and drops_oldest:
            victim = next((entry for entry in self._entries if entry.topic == topic), None)
            if victim is not None:
                self._remove(victim)
                self._count_drop(topic, reported=False)
                full = len(self._entries) >= self.max_messages or self.queued_bytes + size > self.max_bytes
        if full:
            self._count_drop(topic, reported=not drops_oldest)
            return False
        self._entries.append(_Entry(text, topic, drops_oldest, size))
        self._per_topic[topic] = self._per_topic.get(topic, 0) + 1
        self._bytes += size
        self._wakeup.set()
        return True

    @property
    def queued_control_bytes(self) -> int:
        return self._control_bytes

    def put_control(self, text: str, code: str = "status") -> bool:
        """Queue a status reply; False when the bound is reached and it was only counted under `code`."""
        size = utf8_size(text)
        if (
            len(self._control) >= self.max_control
            or self._control_bytes + size > self.max_control_bytes
            or self.queued_bytes + size > self.max_bytes
        ):
            self.control_overflow += 1
            self._suppressed[code] = self._suppressed.get(code, 0) + 1
            self._wakeup.set()
            return False
        self._control.append(text)
        self._control_bytes += size
        self._wakeup.set()
        return True

    def count_lost(self, topic: str, count: int) -> None:
        """Messages of `topic` lost upstream (before the bridge): owed to the client as a `lost` report."""
        self.lost[topic] = self.lost.get(topic, 0) + count
        self._unreported_lost[topic] = self._unreported_lost.get(topic, 0) + count
        self._wakeup.set()

    def take_nowait(self) -> str | None:
        """The next frame to send: owed drop/loss reports and summaries, call replies, status frames, data."""
        if self._unreported:
            counts, self._unreported = self._unreported, {}
            total = sum(counts.values())
            return encode_status(
                Status(
                    "warning",
                    f"dropped {total} message(s) because this client reads too slowly: {counts}",
                    code="dropped",
                    counts=counts,
                )
            )
        if self._unreported_lost:
            counts, self._unreported_lost = self._unreported_lost, {}
            total = sum(counts.values())
            return encode_status(
                Status(
                    "warning",
                    f"{total} message(s) were lost before reaching the bridge (ROS history full): {counts}",
                    code="lost",
                    counts=counts,
                )
            )
        if self._suppressed:
            counts, self._suppressed = self._suppressed, {}
            total = sum(counts.values())
            return encode_status(
                Status(
                    "error",
                    f"{total} more refusal(s) not sent one by one (status replies are bounded): {counts}",
                    code="suppressed",
                    counts=counts,
                )
            )
        # Replies before statuses: a `not_active` answer to a cancel must not overtake the result
        # of the goal that had just ended (the client would take the goal for lost).
        if self._replies:
            text = self._replies.popleft()
            self._reply_bytes -= utf8_size(text)
            return text
        if self._control:
            text = self._control.popleft()
            self._control_bytes -= utf8_size(text)
            return text
        if self._entries:
            entry = self._entries.popleft()
            self._forget(entry)
            return entry.text
        return None

    async def get(self) -> str:
        while True:
            text = self.take_nowait()
            if text is not None:
                return text
            self._wakeup.clear()
            await self._wakeup.wait()

    def _remove(self, entry: _Entry) -> None:
        self._entries.remove(entry)
        self._forget(entry)

    def _forget(self, entry: _Entry) -> None:
        self._bytes -= entry.size
        remaining = self._per_topic[entry.topic] - 1
        if remaining:
            self._per_topic[entry.topic] = remaining
        else:
            del self._per_topic[entry.topic]

    def _count_drop(self, topic: str, reported: bool) -> None:
        self.dropped[topic] = self.dropped.get(topic, 0) + 1
        if reported:
            self._unreported[topic] = self._unreported.get(topic, 0) + 1
            self._wakeup.set()


class TokenBucket:
    """Allows `rate` events per second on average with bursts up to `burst`."""

    def __init__(self, rate: float, burst: int, clock: Callable[[], float] = time.monotonic) -> None:
        self.rate = rate
        self.burst = float(burst)
        self._clock = clock
        self._tokens = float(burst)
        self._last = clock()

    def allow(self) -> bool:
        now = self._clock()
        self._tokens = min(self.burst, self._tokens + (now - self._last) * self.rate)
        self._last = now
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False


class LogLimiter:
    """Lets `rate` log lines per second through (bursts of `burst`); counts the ones it holds back.

    Log lines about what clients do are driven by clients: without a bound, a flood of bad requests
    (or connection attempts) becomes a flood of log lines.
    """

    def __init__(self, rate: float, burst: int = 20, clock: Callable[[], float] = time.monotonic) -> None:
        self._bucket = TokenBucket(rate, burst, clock)
        self._held = 0
        self.suppressed = 0

    def allow(self) -> int | None:
        """None: stay quiet. Otherwise log, mentioning the returned number of lines held back since."""
        if self._bucket.allow():
            held, self._held = self._held, 0
            return held
        self._held += 1
        self.suppressed += 1
        return None
