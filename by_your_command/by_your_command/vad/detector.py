"""The whole VAD pipeline without ROS: any-size audio blocks in, utterance events out."""

from __future__ import annotations

import logging
from typing import Protocol

import numpy as np
import numpy.typing as npt

from by_your_command.audio.pcm import Int16Array, int16_to_float, resample, to_mono
from by_your_command.vad.config import VadConfig
from by_your_command.vad.segmenter import FRAME_SAMPLES, Event, Frame, Segmenter

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000


class ProbabilityModel(Protocol):
    def probability(self, window: npt.NDArray[np.float32]) -> float: ...

    def reset(self) -> None: ...


class Reblocker:
    """Cuts a stream of blocks of any size into fixed frames, each stamped with its first sample's time.

    A block's stamp is trusted only when nothing is buffered; otherwise time continues from the
    buffered samples, so frames stay evenly spaced.
    """

    def __init__(self, frame_samples: int, sample_rate: int) -> None:
        self._frame = frame_samples
        self._rate = sample_rate
        self._buffer = np.zeros(0, dtype=np.int16)
        self._start_ns = 0

    def push(self, pcm: Int16Array, stamp_ns: int) -> list[Frame]:
        if len(self._buffer) == 0:
            self._start_ns = stamp_ns
        self._buffer = np.concatenate([self._buffer, pcm]) if len(self._buffer) else np.array(pcm)
        frames = []
        count = len(self._buffer) // self._frame
        for index in range(count):
            offset = index * self._frame
            frames.append(Frame(self._buffer[offset : offset + self._frame], self._time_at(offset)))
        consumed = count * self._frame
        if consumed:
            self._start_ns = self._time_at(consumed)
            self._buffer = self._buffer[consumed:].copy()
        return frames

    def clear(self) -> None:
        self._buffer = np.zeros(0, dtype=np.int16)

    def _time_at(self, offset: int) -> int:
        return self._start_ns + offset * NS_PER_S // self._rate


class VoiceDetector:
    """Reblocks to 512-sample windows, asks the model, feeds the segmenter."""

    def __init__(self, config: VadConfig, model: ProbabilityModel) -> None:
        self._config = config
        self._model = model
        self._segmenter = Segmenter(config, FRAME_SAMPLES)
        self._reblocker = Reblocker(FRAME_SAMPLES, config.sample_rate)
        self.frames = 0
        self.resampled_blocks = 0
        self.last_probability = 0.0

    @property
    def in_utterance(self) -> bool:
        return self._segmenter.in_utterance

    def process(self, pcm: Int16Array, sample_rate: int, channels: int, stamp_ns: int) -> list[Event]:
        """Feed one block; `stamp_ns` is the time of its first sample. Raises ValueError on bad audio."""
        if channels != 1:
            pcm = to_mono(pcm, channels)
        if sample_rate != self._config.sample_rate:
            if self.resampled_blocks == 0:
                log.warning(
                    "audio arrives at %d Hz; resampling to %d Hz", sample_rate, self._config.sample_rate
                )
            self.resampled_blocks += 1
            pcm = resample(pcm, sample_rate, self._config.sample_rate)
        events: list[Event] = []
        for frame in self._reblocker.push(pcm, stamp_ns):
            self.frames += 1
            self.last_probability = self._model.probability(int16_to_float(frame.samples))
            events.extend(self._segmenter.push(frame, self.last_probability))
        return events

    def stop(self) -> list[Event]:
        """Stop listening (sleep, mute, shutdown): close any utterance and forget buffered audio."""
        events = self._segmenter.finish()
        self._reblocker.clear()
        self._model.reset()
        return events
