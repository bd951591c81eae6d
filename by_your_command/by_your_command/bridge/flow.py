"""Flow control for one client: a bounded send queue with per-class drop policy, and a rate limiter."""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from by_your_command.bridge.protocol import Status, encode_status


@dataclass
class _Entry:
    text: str
    topic: str
    drops_oldest: bool


class SendQueue:
    """Frames waiting for one client's socket, bounded in count and bytes.

    When a topic's share or the whole queue is full:
    - drop-oldest topics (video) replace their own oldest queued frame: only fresh frames matter;
    - every other topic drops the *new* message, counts it and owes the client a `status`
      warning with the counts, sent ahead of the next frame (never a silent loss).
    Status frames (errors, drop reports) bypass the bound: they are few and the client needs them.
    """

    def __init__(self, max_messages: int, max_bytes: int) -> None:
        self.max_messages = max_messages
        self.max_bytes = max_bytes
        self._entries: deque[_Entry] = deque()
        self._control: deque[str] = deque(maxlen=64)
        self._per_topic: dict[str, int] = {}
        self._bytes = 0
        self._unreported: dict[str, int] = {}
        self._wakeup = asyncio.Event()
        self.dropped: dict[str, int] = {}  # every drop by topic (video replacements included)
        self.control_overflow = 0

    @property
    def depth(self) -> int:
        return len(self._entries)

    @property
    def queued_bytes(self) -> int:
        return self._bytes

    def put(self, text: str, topic: str, drops_oldest: bool, topic_limit: int) -> bool:
        """Queue a frame; False when it (or an older one of the same topic) had to be dropped."""
        size = len(text)
        full = (
            self._per_topic.get(topic, 0) >= topic_limit
            or len(self._entries) >= self.max_messages
            or self._bytes + size > self.max_bytes
        )
        if full and drops_oldest:
            victim = next((entry for entry in self._entries if entry.topic == topic), None)
            if victim is not None:
                self._remove(victim)
                self._count_drop(topic, reported=False)
                full = len(self._entries) >= self.max_messages or self._bytes + size > self.max_bytes
        if full:
            self._count_drop(topic, reported=not drops_oldest)
            return False
        self._entries.append(_Entry(text, topic, drops_oldest))
        self._per_topic[topic] = self._per_topic.get(topic, 0) + 1
        self._bytes += size
        self._wakeup.set()
        return True

    def put_control(self, text: str) -> None:
        if len(self._control) == self._control.maxlen:
            self.control_overflow += 1  # a client flooding us with bad requests: keep the newest errors
        self._control.append(text)
        self._wakeup.set()

    def take_nowait(self) -> str | None:
        """The next frame to send: owed drop report, then status frames, then data."""
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
        if self._control:
            return self._control.popleft()
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
        self._bytes -= len(entry.text)
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
