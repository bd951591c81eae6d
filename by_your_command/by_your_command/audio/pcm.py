"""PCM helpers shared by every audio component: int16 <-> float, channel mixing, resampling, WAV."""

from __future__ import annotations

import math
import wave
from fractions import Fraction
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.signal import resample_poly

Int16Array = npt.NDArray[np.int16]
FloatArray = npt.NDArray[np.float32]

INT16_SCALE = 32768.0


def int16_to_float(pcm: Int16Array) -> FloatArray:
    """Scale int16 samples to float32 in [-1, 1)."""
    samples: FloatArray = np.asarray(pcm, dtype=np.int16).astype(np.float32)
    samples /= np.float32(INT16_SCALE)
    return samples


def float_to_int16(samples: npt.ArrayLike) -> Int16Array:
    """Scale float samples in [-1, 1] to int16, clipping what lies outside."""
    scaled = np.rint(np.asarray(samples, dtype=np.float64) * INT16_SCALE)
    return np.clip(scaled, -32768, 32767).astype(np.int16)


def to_mono(pcm: Int16Array, channels: int) -> Int16Array:
    """Average interleaved channels into one; `pcm` length must be a multiple of `channels`."""
    if channels < 1:
        raise ValueError(f"channels must be >= 1, got {channels}")
    if channels == 1:
        return np.asarray(pcm, dtype=np.int16)
    if len(pcm) % channels:
        raise ValueError(f"{len(pcm)} samples is not a whole number of {channels}-channel frames")
    frames = np.asarray(pcm, dtype=np.int32).reshape(-1, channels)
    mono: Int16Array = np.rint(frames.mean(axis=1)).astype(np.int16)
    return mono


def resample(pcm: Int16Array, from_rate: int, to_rate: int) -> Int16Array:
    """Band-limited polyphase resampling of mono int16 audio (e.g. 24 kHz speech to a 16 kHz device).

    Block-by-block use adds small edge effects at block boundaries; for streams use `StreamResampler`.
    """
    if from_rate <= 0 or to_rate <= 0:
        raise ValueError(f"sample rates must be positive, got {from_rate} -> {to_rate}")
    if from_rate == to_rate or len(pcm) == 0:
        return np.asarray(pcm, dtype=np.int16)
    ratio = Fraction(to_rate, from_rate)
    out = resample_poly(int16_to_float(pcm), ratio.numerator, ratio.denominator)
    return float_to_int16(out)


class StreamResampler:
    """Resamples a chunked stream without clicks at chunk edges: each chunk is filtered with the
    previous chunk's tail as left context, and a short right margin is held back until more audio
    (or `flush`) arrives."""

    def __init__(self, from_rate: int, to_rate: int) -> None:
        if from_rate <= 0 or to_rate <= 0:
            raise ValueError(f"sample rates must be positive, got {from_rate} -> {to_rate}")
        ratio = Fraction(to_rate, from_rate)
        self.up, self.down = ratio.numerator, ratio.denominator
        self.margin = self.down * math.ceil(64 / self.down)  # input samples, whole output samples
        self._history = np.zeros(0, dtype=np.float32)
        self._pending = np.zeros(0, dtype=np.float32)

    @property
    def identity(self) -> bool:
        return self.up == self.down

    def push(self, pcm: Int16Array) -> Int16Array:
        if self.identity:
            return np.asarray(pcm, dtype=np.int16)
        self._pending = np.concatenate([self._pending, int16_to_float(pcm)])
        ready = (len(self._pending) - self.margin) // self.down * self.down
        if ready <= 0:
            return np.zeros(0, dtype=np.int16)
        return self._emit(ready, self._pending[ready : ready + self.margin])

    def reset(self) -> None:
        """Forget all context (the stream had a gap): the next push starts a new stream."""
        self._history = self._history[:0]
        self._pending = self._pending[:0]

    def flush(self) -> Int16Array:
        """Everything still held back (the stream paused or ended); the next push starts afresh."""
        if self.identity or len(self._pending) == 0:
            return np.zeros(0, dtype=np.int16)
        out = self._emit(len(self._pending), np.zeros(0, dtype=np.float32))
        self._history = self._history[:0]
        return out

    def _emit(self, count: int, right: FloatArray) -> Int16Array:
        # _history and count are whole multiples of `down` (except at flush), so the output grid
        # of this call continues the previous one exactly.
        body = self._pending[:count]
        out = resample_poly(np.concatenate([self._history, body, right]), self.up, self.down)
        start = len(self._history) * self.up // self.down
        length = math.ceil(count * self.up / self.down)
        self._history = np.concatenate([self._history, body])[-self.margin :]
        self._pending = self._pending[count:]
        return float_to_int16(out[start : start + length])


def read_wav(path: str | Path) -> tuple[Int16Array, int, int]:
    """Read a 16-bit PCM WAV file: (interleaved samples, sample_rate, channels)."""
    with wave.open(str(path), "rb") as wav:
        if wav.getsampwidth() != 2:
            raise ValueError(f"{path}: {8 * wav.getsampwidth()}-bit WAV; only 16-bit PCM is supported")
        frames = wav.readframes(wav.getnframes())
        return np.frombuffer(frames, dtype="<i2").astype(np.int16), wav.getframerate(), wav.getnchannels()


def write_wav(path: str | Path, pcm: Int16Array, sample_rate: int, channels: int = 1) -> None:
    """Write interleaved int16 samples as a 16-bit PCM WAV file."""
    with wave.open(str(path), "wb") as wav:
        wav.setnchannels(channels)
        wav.setsampwidth(2)
        wav.setframerate(sample_rate)
        wav.writeframes(np.asarray(pcm, dtype="<i2").tobytes())


def rms_dbfs(pcm: Int16Array) -> float:
    """Level of a block in dB relative to full scale (-inf for digital silence)."""
    if len(pcm) == 0:
        return float("-inf")
    rms = float(np.sqrt(np.mean(np.square(int16_to_float(pcm), dtype=np.float64))))
    return 20.0 * np.log10(rms) if rms > 0 else float("-inf")
