"""The double-clap detector as it was before issue 8 (fixed 50 ms grid, fixed ZCR threshold), kept
only as the baseline for bench/bench_clap.py. Do not use it anywhere else.

Original docstring follows.

Features per 100 ms analysis window (hop 50 ms, so windows overlap): peak of the smoothed envelope,
zero-crossing rate, spectral centroid, rise time from 20 % of the peak to the peak (the seed's
features), plus the context: the mean level in the 100 ms before the onset and 30-120 ms after
the peak. A clap stands alone; a plosive in speech ("t", "k") is as sharp as a clap but sits
between vowels, which the context catches. A clap found in one window holds off analysis for
`refractory_ms` past its peak, so overlapping windows and its own decay never count it twice.
A clap much weaker than the previous one within the double-clap window is taken for that clap's
room echo and ignored.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from by_your_command.audio.pcm import Int16Array, int16_to_float

SMOOTHING_MS = 2.0  # envelope smoothing: long enough to ride over single zero crossings
ONSET_FRACTION = 0.2
LEAD_MS = 100.0  # context before the onset...
LEAD_GAP_MS = 10.0  # ...ending this long before it
TAIL_START_MS = 30.0  # context after the peak: from here...
TAIL_END_MS = 120.0  # ...to here


@dataclass(frozen=True)
class ClapConfig:
    sample_rate: int = field(default=16000, metadata={"help": "expected input rate (Hz)"})
    zcr_threshold: float = field(default=0.28, metadata={"help": "min zero-crossing rate (crossings/sample)"})
    peak_threshold: float = field(default=0.03, metadata={"help": "min envelope peak (full scale = 1)"})
    max_rise_time_ms: float = field(default=60.0, metadata={"help": "max onset-to-peak time (ms)"})
    min_spectral_centroid: float = field(default=1500.0, metadata={"help": "min spectral centroid (Hz)"})
    double_clap_min_gap_ms: float = field(default=160.0, metadata={"help": "min gap between the claps (ms)"})
    double_clap_max_gap_ms: float = field(default=1200.0, metadata={"help": "max gap between the claps (ms)"})
    max_zcr_difference: float = field(default=0.15, metadata={"help": "the two claps must sound alike"})
    echo_peak_ratio: float = field(
        default=0.35, metadata={"help": "a clap below this fraction of the previous one's peak is its echo"}
    )
    max_context_ratio: float = field(
        default=0.12,
        metadata={"help": "max mean level 100 ms before / 30-120 ms after a clap, relative to its peak"},
    )
    refractory_ms: float = field(default=120.0, metadata={"help": "one clap's decay is not another clap"})
    enabled: bool = field(default=True, metadata={"help": "publish wake_cmd on a double clap"})

    def __post_init__(self) -> None:
        if self.sample_rate <= 0:
            raise ValueError(f"sample_rate must be positive, got {self.sample_rate}")
        if not 0 < self.double_clap_min_gap_ms < self.double_clap_max_gap_ms:
            raise ValueError("need 0 < double_clap_min_gap_ms < double_clap_max_gap_ms")
        if self.refractory_ms >= self.double_clap_min_gap_ms:
            raise ValueError("refractory_ms must be shorter than double_clap_min_gap_ms")


@dataclass(frozen=True)
class ClapFeatures:
    peak: float
    zcr: float
    centroid_hz: float
    rise_ms: float
    lead_ratio: float
    tail_ratio: float


@dataclass(frozen=True)
class Clap:
    time_s: float  # stream time of the envelope peak
    features: ClapFeatures


@dataclass(frozen=True)
class DoubleClap:
    first: Clap
    second: Clap


def window_features(
    segment: npt.NDArray[np.float32], lead: int, window: int, sample_rate: int
) -> tuple[ClapFeatures, int]:
    """Features of segment[lead : lead + window], using the samples around it as context.

    Returns the features and the index of the envelope peak relative to the window start.
    """
    ms = sample_rate / 1000.0
    smoothing = max(int(SMOOTHING_MS * ms), 1)
    envelope = np.convolve(np.abs(segment), np.ones(smoothing) / smoothing, mode="same")
    peak_index = lead + int(np.argmax(envelope[lead : lead + window]))
    peak = float(envelope[peak_index])
    samples = segment[lead : lead + window]
    signs = np.signbit(samples)
    zcr = float(np.count_nonzero(signs[1:] != signs[:-1])) / max(window - 1, 1)
    spectrum = np.abs(np.fft.rfft(samples))
    freqs = np.fft.rfftfreq(window, 1.0 / sample_rate)
    total = float(spectrum.sum())
    centroid = float((freqs * spectrum).sum() / total) if total > 0 else 0.0
    below = np.nonzero(envelope[: peak_index + 1] < ONSET_FRACTION * peak)[0]
    # No quiet point before the peak: the onset is out of sight, so the rise is unknown.
    onset = int(below[-1]) if len(below) else 0
    rise_ms = (peak_index - onset) / ms if len(below) else float("inf")
    before = envelope[max(onset - int(LEAD_MS * ms), 0) : max(onset - int(LEAD_GAP_MS * ms), 0)]
    after = envelope[peak_index + int(TAIL_START_MS * ms) : peak_index + int(TAIL_END_MS * ms)]
    lead_ratio = float(before.mean()) / peak if len(before) and peak > 0 else 0.0
    tail_ratio = float(after.mean()) / peak if len(after) and peak > 0 else 1.0
    return ClapFeatures(peak, zcr, centroid, rise_ms, lead_ratio, tail_ratio), peak_index - lead


class ClapDetector:
    """Feed blocks of any size; returns the claps and double claps they complete."""

    def __init__(self, config: ClapConfig) -> None:
        self._config = config
        rate = config.sample_rate
        self._window = rate // 10
        self._hop = self._window // 2
        # Each analysis looks back LEAD_MS before its window and ahead TAIL_END_MS after it.
        self._lead = int((LEAD_MS + LEAD_GAP_MS) * rate / 1000)
        self._segment = self._lead + self._window + int(TAIL_END_MS * rate / 1000)
        self._refractory = int(config.refractory_ms * rate / 1000)
        self._buffer = np.zeros(self._lead, dtype=np.float32)  # silence before the stream began
        self._buffer_start = 0  # stream sample index of the current window's start
        self._hold_until = 0  # no analysis window may start before this sample
        self._last: Clap | None = None
        self.claps = 0
        self.double_claps = 0

    def is_clap(self, f: ClapFeatures) -> bool:
        c = self._config
        return (
            f.peak >= c.peak_threshold
            and f.zcr >= c.zcr_threshold
            and f.centroid_hz >= c.min_spectral_centroid
            and f.rise_ms <= c.max_rise_time_ms
            and f.lead_ratio <= c.max_context_ratio
            and f.tail_ratio <= c.max_context_ratio
        )

    def process(self, pcm: Int16Array) -> list[Clap | DoubleClap]:
        self._buffer = np.concatenate([self._buffer, int16_to_float(pcm)])
        events: list[Clap | DoubleClap] = []
        while len(self._buffer) >= self._segment:
            start = self._buffer_start
            if start >= self._hold_until:
                events.extend(self._analyse(self._buffer[: self._segment], start))
            self._buffer = self._buffer[self._hop :]
            self._buffer_start += self._hop
        return events

    def _analyse(self, segment: npt.NDArray[np.float32], start: int) -> list[Clap | DoubleClap]:
        window = segment[self._lead : self._lead + self._window]
        if float(np.max(np.abs(window))) < 0.5 * self._config.peak_threshold:
            return []  # cheap reject: most windows are quiet
        features, peak_index = window_features(segment, self._lead, self._window, self._config.sample_rate)
        if not self.is_clap(features):
            return []
        peak_sample = start + peak_index
        self._hold_until = peak_sample + self._refractory
        clap = Clap(peak_sample / self._config.sample_rate, features)
        return self._register(clap)

    def _register(self, clap: Clap) -> list[Clap | DoubleClap]:
        c = self._config
        previous = self._last
        if previous is not None:
            gap_ms = (clap.time_s - previous.time_s) * 1000.0
            if (
                gap_ms <= c.double_clap_max_gap_ms
                and clap.features.peak < c.echo_peak_ratio * previous.features.peak
            ):
                return []  # the room's echo of the previous clap
            if (
                c.double_clap_min_gap_ms <= gap_ms <= c.double_clap_max_gap_ms
                and abs(clap.features.zcr - previous.features.zcr) <= c.max_zcr_difference
            ):
                self._last = None
                self.claps += 1
                self.double_claps += 1
                return [clap, DoubleClap(previous, clap)]
        self._last = clap
        self.claps += 1
        return [clap]
