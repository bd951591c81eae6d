"""The whole VAD pipeline without ROS: any-size audio blocks in, utterance events out."""

from __future__ import annotations

import logging
from fractions import Fraction
from typing import Protocol

import numpy as np
import numpy.typing as npt

from by_your_command.audio.pcm import Int16Array, StreamResampler, int16_to_float, to_mono
from by_your_command.vad.config import VadConfig
from by_your_command.vad.segmenter import FRAME_SAMPLES, Event, Frame, Segmenter
from by_your_command.vad.timeline import Discontinuity, StreamTimeline

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
# Inbound audio is untrusted: bounds that keep one message from stalling or bloating the node.
MIN_INPUT_RATE = 8000
MAX_INPUT_RATE = 192_000
MAX_RATIO_TERM = 1000  # 44100 -> 16000 is 160/441; 44101 Hz would need a 16000/44101 filter
MAX_CHANNELS = 32
MAX_BLOCK_S = 10


class ProbabilityModel(Protocol):
    def probability(self, window: npt.NDArray[np.float32]) -> float: ...

    def reset(self) -> None: ...


def check_rate(sample_rate: int, target_rate: int) -> None:
    """Raise ValueError unless the VAD can take audio at `sample_rate` (cheaply resampled)."""
    if not MIN_INPUT_RATE <= sample_rate <= MAX_INPUT_RATE:
        raise ValueError(f"sample_rate {sample_rate} Hz is outside {MIN_INPUT_RATE}..{MAX_INPUT_RATE}")
    ratio = Fraction(target_rate, sample_rate)
    if max(ratio.numerator, ratio.denominator) > MAX_RATIO_TERM:
        raise ValueError(f"sample_rate {sample_rate} Hz cannot be resampled to {target_rate} Hz cheaply")


def check_block(samples: int, sample_rate: int, channels: int) -> None:
    """Raise ValueError for a block the VAD must not try to process (its rate already checked)."""
    if not 1 <= channels <= MAX_CHANNELS:
        raise ValueError(f"channels must be in 1..{MAX_CHANNELS}, got {channels}")
    if samples > MAX_BLOCK_S * sample_rate * channels:
        raise ValueError(f"block of {samples} samples is longer than {MAX_BLOCK_S} s")


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


class ContinuousResampler:
    """One `StreamResampler` for the current input rate, and the time of each output's first sample
    (the resampler holds a little input back, so output starts slightly before the block's stamp)."""

    def __init__(self, to_rate: int) -> None:
        self._to_rate = to_rate
        self._resampler: StreamResampler | None = None
        self._rate = 0
        self._received = 0  # input samples since the stream started
        self._emitted = 0  # output samples since the stream started

    def push(self, pcm: Int16Array, sample_rate: int, stamp_ns: int) -> tuple[Int16Array, int]:
        resampler = self._resampler
        if resampler is None or sample_rate != self._rate:
            resampler = self._resampler = StreamResampler(sample_rate, self._to_rate)
            self._rate = sample_rate
            self._received = self._emitted = 0
        # Output j sits at input position j * down / up: how far before this block's start is it?
        behind = self._received * resampler.up - self._emitted * resampler.down
        start_ns = stamp_ns - behind * NS_PER_S // (resampler.up * sample_rate)
        out = resampler.push(pcm)
        self._received += len(pcm)
        self._emitted += len(out)
        return out, start_ns

    def reset(self) -> None:
        """A new stream starts (gap, rate change, sleep): no context from before it."""
        if self._resampler is not None:
            self._resampler.reset()
        self._received = self._emitted = 0


class VoiceDetector:
    """Checks continuity, resamples, reblocks to 512-sample windows, asks the model, feeds the segmenter."""

    def __init__(self, config: VadConfig, model: ProbabilityModel) -> None:
        self._config = config
        self._model = model
        self._segmenter = Segmenter(config, FRAME_SAMPLES)
        self._reblocker = Reblocker(FRAME_SAMPLES, config.sample_rate)
        self._resampler = ContinuousResampler(config.sample_rate)
        self._timeline = StreamTimeline(config.gap_tolerance_ns)
        self.frames = 0
        self.resampled_blocks = 0
        self.discontinuities = 0
        self.last_discontinuity: Discontinuity | None = None
        self.last_probability = 0.0
        self._rate_ok = config.sample_rate  # the last input rate that passed check_rate

    @property
    def in_utterance(self) -> bool:
        return self._segmenter.in_utterance

    @property
    def streaming(self) -> bool:
        """Audio has arrived since the start or the last `stop()`."""
        return self._timeline.running

    def process(
        self, pcm: Int16Array, sample_rate: int, channels: int, stamp_ns: int, stamped: bool = True
    ) -> list[Event]:
        """Feed one block; `stamp_ns` is the time of its first sample. Raises ValueError on bad audio.

        With `stamped=False` (the sender left the stamp empty) the block is taken to continue the
        stream, and `stamp_ns` (its arrival time) is used only when it starts a new one.
        """
        if sample_rate != self._rate_ok:
            check_rate(sample_rate, self._config.sample_rate)
            self._rate_ok = sample_rate
        check_block(len(pcm), sample_rate, channels)
        mono = to_mono(pcm, channels)
        placement = self._timeline.place(stamp_ns, stamped, len(mono), sample_rate)
        events: list[Event] = []
        if placement.discontinuity is not None:
            # Nothing from before the gap may join what follows: close, forget pre-roll and state.
            self.discontinuities += 1
            self.last_discontinuity = placement.discontinuity
            events += self._restart()
        if sample_rate != self._config.sample_rate:
            if self.resampled_blocks == 0:
                log.warning(
                    "audio arrives at %d Hz; resampling to %d Hz", sample_rate, self._config.sample_rate
                )
            self.resampled_blocks += 1
            mono, start_ns = self._resampler.push(mono, sample_rate, placement.stamp_ns)
        else:
            start_ns = placement.stamp_ns
        for frame in self._reblocker.push(mono, start_ns):
            self.frames += 1
            self.last_probability = self._model.probability(int16_to_float(frame.samples))
            events.extend(self._segmenter.push(frame, self.last_probability))
        return events

    def stop(self) -> list[Event]:
        """Stop listening (sleep, mute, audio timeout, shutdown): close any utterance, forget the
        stream; the next block starts a new one at its own stamp."""
        self._timeline.reset()
        return self._restart()

    def _restart(self) -> list[Event]:
        events = self._segmenter.finish()
        self._reblocker.clear()
        self._resampler.reset()
        self._model.reset()
        return events
