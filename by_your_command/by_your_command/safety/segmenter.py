"""Short utterances cut from a stream by level alone: cheap enough to run on every block.

A tracked noise floor decides which 20 ms frames are speech; an utterance ends after
`end_silence_ms` of quiet. Over the robot's voice its residual echo stays above the floor after
the user's word: `Paused` says the utterance has been well under its loudest that long. Speech
longer than `max_utterance_ms` is a sentence, not a stop: it is abandoned (never decoded) until
the next pause, which keeps the recogniser idle through talk. Nothing here is decoded: the caller
hands the frames to the recogniser as they come, so the decode is done when the utterance ends
(the end of the word to a stop is the quiet that ends it plus a few ms).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from by_your_command.audio.pcm import Int16Array

RATE = 16000
FRAME = 320  # 20 ms
NS_PER_S = 1_000_000_000
PRE_ROLL_FRAMES = 8  # 160 ms before the onset: the word's soft start (an /s/ is quiet)
FLOOR_RISE_DB_PER_FRAME = 0.02  # 1 dB/s: a steady noise (a fan) joins the floor, speech does not
FLOOR_START_DB = -70.0


@dataclass(frozen=True)
class Started:
    start_ns: int  # first sample handed over (pre-roll included)


@dataclass(frozen=True)
class Audio:
    pcm: Int16Array


@dataclass(frozen=True)
class Ended:
    voice_start_ns: int  # first frame judged speech
    voice_end_ns: int  # end of the last frame judged speech: the end of the word


@dataclass(frozen=True)
class Paused:
    """`end_silence_ms` under the utterance's loudest by `end_drop_db`, though not yet quiet: the
    word may be over and what goes on the robot's residual echo (or it is a weak consonant)."""

    voice_start_ns: int
    voice_end_ns: int  # end of the last frame within end_drop_db of the loudest


@dataclass(frozen=True)
class Abandoned:
    """The open utterance grew into a sentence: drop what was decoded."""


SegmentEvent = Started | Audio | Paused | Ended | Abandoned


def level_dbfs(frame: Int16Array) -> float:
    power = float(np.mean(np.square(frame.astype(np.float64)))) / (32768.0 * 32768.0)
    return 10.0 * math.log10(power + 1e-12)


class LevelSegmenter:
    """16 kHz mono frames in, utterance events out. Not thread-safe."""

    def __init__(
        self,
        min_level_dbfs: float,
        onset_db: float,
        end_silence_ms: int,
        max_utterance_ms: int,
        end_drop_db: float | None = None,
    ) -> None:
        self._min_level = min_level_dbfs
        # Inside an utterance, `end_silence_ms` this far under its loudest is a pause (`Paused`),
        # however far above the noise floor (None: no pauses). Set by the caller while it applies.
        self.end_drop_db = end_drop_db
        self._onset = onset_db
        self._end_frames = max(1, end_silence_ms * RATE // 1000 // FRAME)
        self._max_frames = max(1, max_utterance_ms * RATE // 1000 // FRAME)
        self.floor_db = FLOOR_START_DB
        self._pending = np.zeros(0, dtype=np.int16)
        self._next_ns: int | None = None  # stamp of _pending[0]
        self._pre_roll: deque[tuple[int, Int16Array]] = deque(maxlen=PRE_ROLL_FRAMES)
        self._open = False  # inside an utterance being handed over
        self._long = False  # inside speech too long to be a stop: wait for its end
        self._voiced = 0  # frames judged speech in the open utterance
        self._quiet = 0  # frames of quiet since the last speech frame
        self._voice_start = 0
        self._voice_end = 0
        self._peak_db = -120.0
        self._under = 0  # frames under the loudest by end_drop_db since the last loud one
        self._loud_end = 0
        self.frames = 0
        self.utterances = 0
        self.abandoned = 0

    @property
    def active(self) -> bool:
        """Inside speech (an utterance or a sentence)."""
        return self._open or self._long

    def close(self) -> list[SegmentEvent]:
        """The stream stopped (the player plays nothing more): the open utterance ends here."""
        events: list[SegmentEvent] = []
        if self._open:
            self.utterances += 1
            events.append(Ended(self._voice_start, self._voice_end))
        self.reset()
        return events

    def reset(self) -> list[SegmentEvent]:
        """A gap in the stream: the open utterance is dropped."""
        events: list[SegmentEvent] = [Abandoned()] if self._open else []
        self._pending = np.zeros(0, dtype=np.int16)
        self._next_ns = None
        self._pre_roll.clear()
        self._open = self._long = False
        self._quiet = self._voiced = 0
        return events

    def push(self, pcm: Int16Array, start_ns: int) -> list[SegmentEvent]:
        if self._next_ns is None or not self._pending.size:
            self._next_ns = start_ns - len(self._pending) * NS_PER_S // RATE
        self._pending = np.concatenate([self._pending, pcm]) if self._pending.size else pcm
        events: list[SegmentEvent] = []
        count = len(self._pending) // FRAME
        for index in range(count):
            frame = self._pending[index * FRAME : (index + 1) * FRAME]
            stamp = self._next_ns + index * FRAME * NS_PER_S // RATE
            self._frame(frame, stamp, events)
        self._pending = self._pending[count * FRAME :]
        self._next_ns += count * FRAME * NS_PER_S // RATE
        return events

    def _frame(self, frame: Int16Array, stamp: int, events: list[SegmentEvent]) -> None:
        self.frames += 1
        level = level_dbfs(frame)
        speech = level >= max(self._min_level, self.floor_db + self._onset)
        if not speech and not self.active:
            # The floor follows quiet down at once and creeps up slowly.
            self.floor_db = min(level, self.floor_db + FLOOR_RISE_DB_PER_FRAME)
        end = stamp + FRAME * NS_PER_S // RATE
        if self._long:
            self._quiet = 0 if speech else self._quiet + 1
            if self._quiet >= self._end_frames:
                self._long = False
                self._quiet = 0
            return
        if not self._open:
            if not speech:
                self._pre_roll.append((stamp, frame))
                return
            self._open = True
            self._peak_db = level
            self._voiced, self._quiet, self._under = 0, 0, 0
            self._voice_start = stamp
            first = self._pre_roll[0][0] if self._pre_roll else stamp
            events.append(Started(first))
            events.extend(Audio(f) for _, f in self._pre_roll)
            self._pre_roll.clear()
        events.append(Audio(frame))
        self._track_pause(level if speech else -120.0, end, events)
        if speech:
            self._voiced += 1
            self._quiet = 0
            self._voice_end = end
            if self._voiced > self._max_frames:
                self._open, self._long = False, True
                self.abandoned += 1
                events.append(Abandoned())
            return
        self._quiet += 1
        if self._quiet >= self._end_frames:
            if events and isinstance(events[-1], Paused):
                events.pop()  # it ends here anyway
            self._open = False
            self._quiet = 0
            self.utterances += 1
            events.append(Ended(self._voice_start, self._voice_end))

    def _track_pause(self, level: float, end: int, events: list[SegmentEvent]) -> None:
        if level >= self._peak_db - (self.end_drop_db or 0.0):
            self._peak_db = max(self._peak_db, level)
            self._under, self._loud_end = 0, end
            return
        self._under += 1
        if self.end_drop_db is not None and self._under == self._end_frames:
            events.append(Paused(self._voice_start, self._loud_end))
