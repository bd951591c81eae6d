"""PCM helpers shared by every audio component: int16 <-> float, channel mixing, resampling, WAV."""

from __future__ import annotations

import wave
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.signal import firwin, resample_poly, upfirdn

Int16Array = npt.NDArray[np.int16]
FloatArray = npt.NDArray[np.float32]

INT16_SCALE = 32768.0
NS_PER_S = 1_000_000_000


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


MAX_SAMPLE_RATE = 768_000
MAX_RATIO_TERM = 1000  # resampling filters have 20 * max(up, down) + 1 taps: bound their size


def check_sample_rate(rate: int) -> None:
    """Raise ValueError unless `rate` is a sample rate audio hardware could plausibly produce."""
    if not 0 < rate <= MAX_SAMPLE_RATE:
        raise ValueError(f"sample rate must be in 1..{MAX_SAMPLE_RATE} Hz, got {rate}")


class StreamResampler:
    """Resamples a chunked stream exactly as one `resample()` of the whole stream would.

    Output sample j sits at input position j * down / up and is the same polyphase FIR as
    scipy's `resample_poly` (Kaiser window, 10 * max(up, down) taps either side at the upsampled
    rate). It is computed once, as soon as the input it depends on has arrived; so chunk edges
    leave no clicks, nothing drifts, and only the filter's reach is held back: 10 / min(rates)
    s (0.6 ms at 16 kHz) until more audio or `flush` comes.
    """

    def __init__(self, from_rate: int, to_rate: int) -> None:
        check_sample_rate(from_rate)
        check_sample_rate(to_rate)
        ratio = Fraction(to_rate, from_rate)
        if max(ratio.numerator, ratio.denominator) > MAX_RATIO_TERM:
            raise ValueError(
                f"cannot resample {from_rate} -> {to_rate} Hz: ratio {ratio} needs a filter too long"
            )
        self.from_rate, self.to_rate = from_rate, to_rate
        self.up, self.down = ratio.numerator, ratio.denominator
        self._half_len = 10 * max(self.up, self.down)  # in upsampled samples, as resample_poly
        # Zero-pad the filter in front so that output k of upfirdn is centred on input k * down / up.
        pre_pad = self.down - self._half_len % self.down
        taps = np.zeros(1) if self.identity else self._lowpass()
        self._taps = np.concatenate([np.zeros(pre_pad), taps * self.up]).astype(np.float32)
        self._skip = (self._half_len + pre_pad) // self.down  # upfirdn outputs before output 0
        self._buffer = np.zeros(0, dtype=np.float32)  # input from index _base on
        self._base = 0  # stream index of _buffer[0]; a multiple of `down` keeps the output grid
        self.received = 0  # input samples pushed since the stream started
        self.emitted = 0  # output samples returned since the stream started

    @property
    def identity(self) -> bool:
        return self.up == self.down

    def _lowpass(self) -> npt.NDArray[np.float64]:
        taps: npt.NDArray[np.float64] = firwin(
            2 * self._half_len + 1, 1.0 / max(self.up, self.down), window=("kaiser", 5.0)
        )
        return taps

    @property
    def held_back_s(self) -> float:
        """Input received whose output is not out yet, in seconds (the added latency now)."""
        return (self.received - self.emitted * self.down / self.up) / self.from_rate

    def push(self, pcm: Int16Array) -> Int16Array:
        """Resampled audio as far as the input so far allows (possibly empty)."""
        samples = np.asarray(pcm, dtype=np.int16)
        self.received += len(samples)
        if self.identity:
            self.emitted += len(samples)
            return samples
        self._buffer = np.concatenate([self._buffer, int16_to_float(samples)])
        # Output j needs input up to (j * down + half_len) / up: emit those whose input is all here.
        ready = (self.up * self.received - 1 - self._half_len) // self.down + 1
        return self._emit(max(ready, self.emitted))

    def flush(self) -> Int16Array:
        """Everything still held back, as if the stream ended here; the next push starts afresh."""
        if self.identity:
            self.reset()
            return np.zeros(0, dtype=np.int16)
        total = -(-self.received * self.up // self.down)  # ceil: the length resample() gives
        reach = self._half_len // self.up + 1
        self._buffer = np.concatenate([self._buffer, np.zeros(reach + self.down, dtype=np.float32)])
        out = self._emit(total)
        self.reset()
        return out

    def reset(self) -> None:
        """Forget all context (the stream had a gap): the next push starts a new stream."""
        self._buffer = np.zeros(0, dtype=np.float32)
        self._base = self.received = self.emitted = 0

    def _emit(self, end: int) -> Int16Array:
        if end <= self.emitted:
            return np.zeros(0, dtype=np.int16)
        offset = self._base * self.up // self.down  # output index of the buffer's first sample
        filtered = upfirdn(self._taps, self._buffer, self.up, self.down)
        first = self._skip + self.emitted - offset
        out = float_to_int16(filtered[first : first + end - self.emitted])
        self.emitted = end
        # Keep the input the next output still needs, from a multiple of `down` on.
        needed = (self.emitted * self.down - self._half_len) // self.up
        base = max(self._base, needed // self.down * self.down)
        self._buffer = self._buffer[base - self._base :]
        self._base = base
        return out


@dataclass(frozen=True)
class StampedPcm:
    """Samples and the time (ns) of the first one; `restart` marks the first piece of a new stream."""

    pcm: Int16Array
    start_ns: int
    restart: bool = False


class StampedResampler:
    """A live stream of blocks stamped with their first sample's time (ns), brought to `to_rate`
    with a `StreamResampler` and stamped the same way on the way out.

    The stream restarts, its held-back tail flushed first, when the rate changes or a stamp is
    more than `tolerance_ns` away from where the samples so far put it (a lost block, a jump
    back); `restarts` counts those. Each piece keeps the time of its samples: a restart never
    shifts the timeline, and the first piece of a new stream says so (`restart`).
    """

    def __init__(self, to_rate: int, tolerance_ns: int) -> None:
        check_sample_rate(to_rate)
        self.to_rate = to_rate
        self.tolerance_ns = tolerance_ns
        self.restarts = 0
        self._resampler: StreamResampler | None = None
        self._open = False  # a stream is running (pushed to and not flushed since)
        self._fresh = False  # the running stream has not produced a piece yet
        self._origin_ns = 0  # time of the running stream's first input sample

    @property
    def resampling(self) -> bool:
        return self._resampler is not None and not self._resampler.identity

    @property
    def held_back_s(self) -> float:
        return self._resampler.held_back_s if self._resampler is not None and self._open else 0.0

    def push(self, pcm: Int16Array, sample_rate: int, start_ns: int) -> list[StampedPcm]:
        """Mono int16 `pcm` at `sample_rate` captured from `start_ns`: the pieces ready to go on."""
        pieces: list[StampedPcm] = []
        resampler = self._resampler
        if resampler is None or not self._continues(resampler, sample_rate, start_ns):
            if resampler is not None and self._open:  # a gap, a jump or a new rate mid-stream
                self.restarts += 1
                pieces += self.flush()
            if resampler is None or resampler.from_rate != sample_rate:
                resampler = self._resampler = StreamResampler(sample_rate, self.to_rate)
            self._origin_ns = start_ns
            self._open = self._fresh = True
        first = resampler.emitted
        out = resampler.push(pcm)
        if len(out):
            pieces.append(StampedPcm(out, self._time_of(first), self._fresh))
            self._fresh = False
        return pieces

    def flush(self) -> list[StampedPcm]:
        """The held-back tail of the running stream (it paused or ended); the next push restarts."""
        if self._resampler is None or not self._open:
            return []
        first = self._resampler.emitted
        tail = self._resampler.flush()
        self._open = False
        if len(tail) == 0:
            return []
        piece = StampedPcm(tail, self._time_of(first), self._fresh)
        self._fresh = False
        return [piece]

    def _continues(self, resampler: StreamResampler, sample_rate: int, start_ns: int) -> bool:
        if not self._open or resampler.from_rate != sample_rate:
            return False
        expected = self._origin_ns + resampler.received * NS_PER_S // resampler.from_rate
        return abs(start_ns - expected) <= self.tolerance_ns

    def _time_of(self, output_index: int) -> int:
        return self._origin_ns + output_index * NS_PER_S // self.to_rate


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
