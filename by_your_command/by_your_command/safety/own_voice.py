"""The robot's own voice must never stop it: it says "Stopping." itself, and replies say "stop".

The player publishes what it plays (`audio_played`, stamped with the play time). The same
segmenter and recogniser run on that clean reference, and every stop-like word the robot said
("stop", "stopping", "halted"...) is remembered with its time. A stop heard in the microphone
within `window` of one of them is the robot hearing itself, wherever the room's delay puts it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

NS_PER_S = 1_000_000_000
KEEP_NS = 10 * NS_PER_S  # the room's delay is well under a second: older marks are useless


@dataclass(frozen=True)
class Span:
    start_ns: int
    end_ns: int


class OwnVoiceMarks:
    """Times at which the robot said a stop-like word."""

    def __init__(self, window_ms: int) -> None:
        self._window = window_ms * 1_000_000
        self._marks: deque[Span] = deque(maxlen=256)
        self.marked = 0

    def mark(self, start_ns: int, end_ns: int) -> None:
        self._marks.append(Span(start_ns, end_ns))
        self.marked += 1
        while self._marks and self._marks[0].end_ns < end_ns - KEEP_NS:
            self._marks.popleft()

    def covers(self, start_ns: int, end_ns: int) -> bool:
        """The robot said a stop-like word overlapping [start, end] widened by the window."""
        return any(
            mark.start_ns - self._window <= end_ns and start_ns <= mark.end_ns + self._window
            for mark in self._marks
        )
