"""Utterance segmenter: speech probabilities per frame in, voice-activity and chunk events out.

Independent of the model so its invariants can be property-tested. Guarantees for every utterance:
- exactly one chunk has is_utterance_end=True, and it is the last one (it may be empty);
- chunk_sequence runs 0, 1, 2, ... without gaps;
- the chunks concatenated are the frames from the first pre-roll frame to the end, each once;
- utterance_id is the time (ns) of the first sample emitted (the first pre-roll frame);
- unvoiced_samples counts, up to the end of each chunk, the samples not judged speech: the pre-roll
  and every frame of a silence run (the closing silence included), so a listener can tell how much
  speech it has heard (a barge-in judge must not count the pre-roll).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from by_your_command.audio.pcm import Int16Array
from by_your_command.vad.config import VadConfig

FRAME_SAMPLES = 512


@dataclass(frozen=True)
class VoiceActivity:
    active: bool
    time_ns: int


@dataclass(frozen=True)
class UtteranceChunk:
    utterance_id: int
    chunk_sequence: int
    samples: Int16Array
    is_utterance_end: bool
    sample_rate: int
    unvoiced_samples: int = 0  # of the utterance up to the end of this chunk: not speech


Event = VoiceActivity | UtteranceChunk


@dataclass(frozen=True)
class Frame:
    samples: Int16Array
    time_ns: int  # time of the first sample


class Segmenter:
    def __init__(self, config: VadConfig, frame_samples: int = FRAME_SAMPLES) -> None:
        self._config = config
        self._threshold = config.threshold
        self._neg_threshold = config.effective_neg_threshold
        self._min_silence = config.min_silence_frames(frame_samples)
        self._chunk_frames = config.frames_per_chunk
        self._pre_roll: deque[Frame] = deque(maxlen=config.pre_roll_frames)
        self._pending: list[Frame] = []
        self._pending_voiced: list[bool] = []  # per pending frame: judged speech
        self._unvoiced = 0  # samples of the utterance emitted so far that were not speech
        self._in_utterance = False
        self._utterance_id = 0
        self._sequence = 0
        self._silent_frames = 0

    @property
    def in_utterance(self) -> bool:
        return self._in_utterance

    def push(self, frame: Frame, probability: float) -> list[Event]:
        if not self._in_utterance:
            if probability < self._threshold:
                self._pre_roll.append(frame)
                return []
            return self._start(frame)
        self._pending.append(frame)
        if probability >= self._threshold:
            self._silent_frames = 0
        elif self._silent_frames > 0 or probability < self._neg_threshold:
            # Hysteresis: silence starts below neg_threshold and only speech >= threshold stops it.
            self._silent_frames += 1
        self._pending_voiced.append(self._silent_frames == 0)
        if self._silent_frames >= self._min_silence:
            return self._close()
        return self._emit_full_chunks()

    def finish(self) -> list[Event]:
        """Close an open utterance now (sleep, mute, end of stream) and forget the pre-roll."""
        self._pre_roll.clear()
        return self._close() if self._in_utterance else []

    def _start(self, frame: Frame) -> list[Event]:
        self._pending = [*self._pre_roll, frame]
        self._pending_voiced = [False] * len(self._pre_roll) + [True]
        self._pre_roll.clear()
        self._in_utterance = True
        self._utterance_id = self._pending[0].time_ns
        self._sequence = 0
        self._unvoiced = 0
        self._silent_frames = 0
        return [VoiceActivity(True, frame.time_ns), *self._emit_full_chunks()]

    def _emit_full_chunks(self) -> list[Event]:
        events: list[Event] = []
        while len(self._pending) >= self._chunk_frames:
            events.append(self._chunk(self._chunk_frames, end=False))
        return events

    def _close(self) -> list[Event]:
        end_time = self._pending[-1].time_ns if self._pending else self._utterance_id
        events: list[Event] = [self._chunk(len(self._pending), end=True), VoiceActivity(False, end_time)]
        self._in_utterance = False
        self._silent_frames = 0
        return events

    def _chunk(self, count: int, end: bool) -> UtteranceChunk:
        """The first `count` pending frames as the next chunk (taken off the pending list)."""
        frames, voiced = self._pending[:count], self._pending_voiced[:count]
        del self._pending[:count], self._pending_voiced[:count]
        samples = (
            np.concatenate([f.samples for f in frames]).astype(np.int16, copy=False)
            if frames
            else np.zeros(0, dtype=np.int16)
        )
        self._unvoiced += sum(len(f.samples) for f, speech in zip(frames, voiced, strict=True) if not speech)
        chunk = UtteranceChunk(
            self._utterance_id, self._sequence, samples, end, self._config.sample_rate, self._unvoiced
        )
        self._sequence += 1
        return chunk
