"""What a sound around an onset looks like, measured on a window aligned to that onset.

Every level is relative (to the sound's own peak or to the room's noise floor just before it), so
the same clap measures the same in a quiet or noisy room, near or far. The features separate a
clap from the other sharp sounds a microphone hears, mostly speech plosives ("t", "k", "p"):
- a clap stands out of the room's noise floor (`snr_db`) and of what came just before (`lead_db`);
- it rises within a few ms and dies away (room reverb only) within tens of ms: `rise_ms`,
  `decay_db`, `tail_db`; a plosive runs into a vowel;
- nothing voiced (periodic, as vowels are) is close before or after it: `voiced_frames`.
The measurement depends only on the segment's samples, so it is the same however the stream was
cut into blocks.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.signal import butter, sosfilt

Float64Array = npt.NDArray[np.float64]

HIGH_PASS_HZ = 100.0  # below: rumble, handling noise, DC
ENERGY_MS = 1.0  # the energy envelope's window
PEAK_SEARCH_MS = 25.0  # the peak is looked for this long after the onset (early reflections add up)
RISE_TO_DB = 6.0  # the rise ends when the energy is this close to its peak
FLOOR_MS = 1500.0  # how far back the room's noise floor is measured
FLOOR_FRAME_MS = 16.0
FLOOR_PERCENTILE = 10.0  # the room's noise floor: a quiet moment of the last FLOOR_MS
FLOOR_GAP_MS = 5.0  # the floor is measured up to this long before the onset
DECAY_FROM_MS = 30.0  # the clap's tail is measured from this long after its peak...
DECAY_TO_MS = 100.0  # ...to this long (its mean), and TAIL_TO_MS (its loudest moment)
LEAD_FROM_MS = 120.0  # what came before the onset: from this long before it...
LEAD_TO_MS = 10.0  # ...to this long (longer would reach the first clap of a fast double clap)
TAIL_TO_MS = 140.0
LOUDNESS_FRAME_MS = 10.0  # lead and tail compare the peak with their loudest frame of this length
CENTROID_MS = 16.0  # the burst whose spectral centroid is compared between two claps
VOICING_FRAME_MS = 40.0
VOICING_LOW_PASS_HZ = 1000.0  # periodicity is looked for below: jitter blurs the higher harmonics
LOW_BAND_VOICING_THRESHOLD = 0.8  # the low band alone must be clearly periodic
MIN_PITCH_HZ = 40.0  # creaky and deep voices go below 60 Hz
MAX_PITCH_HZ = 400.0
VOICING_GUARD_MS = 20.0  # voicing is looked for from this far from the burst (its own samples excluded)
RELEVANT_OVER_FLOOR_DB = 10.0  # a context frame must be this far above the floor to count as sound
LOG_EPS = 1e-20
DIGITAL_SILENCE = 1e-14  # mean square (full scale 1) of an all-zero stretch after the high-pass


@dataclass(frozen=True)
class ClapFeatures:
    peak: float  # largest sample from the onset to the energy peak (full scale 1)
    level_dbfs: float  # 1-ms energy at its peak, dB full scale
    snr_db: float  # that peak over the room's noise floor before the onset
    rise_ms: float  # from the onset until the energy is within RISE_TO_DB of its peak
    decay_db: float  # the peak over the mean energy DECAY_FROM_MS..DECAY_TO_MS after it
    lead_db: float  # the peak over the loudest 10 ms in LEAD_FROM_MS..LEAD_TO_MS before the onset
    tail_db: float  # the peak over the loudest 10 ms in DECAY_FROM_MS..TAIL_TO_MS after the peak
    voiced_frames: int  # voiced frames (periodic, not quiet) within the context either side
    centroid_hz: float  # spectral centroid of the burst


@dataclass(frozen=True)
class FeatureWindow:
    """Where the features look, around an onset (in samples at `sample_rate`)."""

    sample_rate: int
    before: int  # samples of the segment before the onset (noise floor and leading context)
    after: int  # samples after it (rise, decay, trailing context)
    context: int  # how far either side voicing is looked for
    context_level_db: float  # context frames this far below the clap's peak do not count
    voicing_threshold: float  # normalised autocorrelation from which a frame counts as voiced

    @classmethod
    def build(
        cls,
        sample_rate: int,
        context_ms: float,
        context_level_db: float,
        voicing_threshold: float,
    ) -> FeatureWindow:
        def samples(ms: float) -> int:
            return int(round(ms * sample_rate / 1000))

        after = samples(PEAK_SEARCH_MS + max(context_ms, TAIL_TO_MS))
        before = samples(max(FLOOR_MS, context_ms, LEAD_FROM_MS) + ENERGY_MS + FLOOR_FRAME_MS)
        return cls(sample_rate, before, after, samples(context_ms), context_level_db, voicing_threshold)


def _db(value: float) -> float:
    return 10.0 * float(np.log10(max(value, LOG_EPS)))


class FeatureMeter:
    """Measures `ClapFeatures` on segments of `window.before + window.after` int16-scaled samples
    whose onset is at index `window.before`."""

    def __init__(self, window: FeatureWindow) -> None:
        self.window = window
        rate = window.sample_rate
        self._sos = butter(2, HIGH_PASS_HZ, btype="highpass", fs=rate, output="sos")
        self._voicing_band = butter(4, VOICING_LOW_PASS_HZ, btype="lowpass", fs=rate, output="sos")
        self._energy = max(int(ENERGY_MS * rate / 1000), 1)
        self._peak_search = int(PEAK_SEARCH_MS * rate / 1000)
        self._floor_frame = max(int(FLOOR_FRAME_MS * rate / 1000), 1)
        self._floor_gap = int(FLOOR_GAP_MS * rate / 1000)
        self._decay = (int(DECAY_FROM_MS * rate / 1000), int(DECAY_TO_MS * rate / 1000))
        self._lead = (int(LEAD_FROM_MS * rate / 1000), int(LEAD_TO_MS * rate / 1000))
        self._tail_to = int(TAIL_TO_MS * rate / 1000)
        self._loudness_frame = int(LOUDNESS_FRAME_MS * rate / 1000)
        self._centroid = max(int(CENTROID_MS * rate / 1000), 8)
        self._frame = int(VOICING_FRAME_MS * rate / 1000)
        self._lags = (int(rate / MAX_PITCH_HZ), int(rate / MIN_PITCH_HZ))
        self._guard = int(VOICING_GUARD_MS * rate / 1000)
        self._fft = 1 << int(np.ceil(np.log2(self._frame + self._lags[1] + 1)))

    def measure(self, segment: npt.NDArray[np.int16]) -> ClapFeatures:
        w = self.window
        x: Float64Array = sosfilt(self._sos, segment.astype(np.float64) / 32768.0)
        onset = w.before
        squares = x * x
        cumulative = np.concatenate([[0.0], np.cumsum(squares)])
        # energy[k] = mean square of x[k - energy + 1 .. k]
        energy = np.zeros(len(x))
        energy[self._energy - 1 :] = (cumulative[self._energy :] - cumulative[: -self._energy]) / self._energy
        search = energy[onset : onset + self._peak_search]
        peak_at = onset + int(np.argmax(search))
        peak_energy = float(energy[peak_at])
        # Rise: until the energy first comes within RISE_TO_DB of its peak (a reflection may peak later).
        risen = int(np.argmax(search >= peak_energy * 10.0 ** (-RISE_TO_DB / 10.0)))
        peak = float(np.abs(segment[onset - self._energy : peak_at + 1]).max()) / 32768.0
        floor = self._floor(squares, onset)
        tail = squares[peak_at + self._decay[0] : peak_at + self._decay[1]]
        burst = x[max(peak_at - self._energy, 0) : max(peak_at - self._energy, 0) + self._centroid]
        spectrum = np.abs(np.fft.rfft(burst * np.hanning(len(burst))))
        freqs = np.fft.rfftfreq(len(burst), 1.0 / w.sample_rate)
        centroid = float((freqs * spectrum).sum() / max(float(spectrum.sum()), LOG_EPS))
        # Context quieter than this is too faint to matter: far below the clap or near the floor.
        relevant = max(
            peak_energy * 10.0 ** (-w.context_level_db / 10.0),
            floor * 10.0 ** (RELEVANT_OVER_FLOOR_DB / 10.0),
        )
        return ClapFeatures(
            peak=peak,
            level_dbfs=_db(peak_energy),
            snr_db=_db(peak_energy) - _db(floor),
            rise_ms=risen * 1000.0 / w.sample_rate,
            decay_db=_db(peak_energy) - _db(float(tail.mean())),
            lead_db=_db(peak_energy)
            - _db(self._loudest(cumulative, onset - self._lead[0], onset - self._lead[1])),
            tail_db=_db(peak_energy)
            - _db(self._loudest(cumulative, peak_at + self._decay[0], peak_at + self._tail_to)),
            voiced_frames=self._voiced_frames(x, onset, peak_at, relevant),
            centroid_hz=centroid,
        )

    def _loudest(self, cumulative: Float64Array, start: int, end: int) -> float:
        """Mean square of the loudest 10 ms frame in [start, end) (frames hop 5 ms)."""
        frame = self._loudness_frame
        starts = np.arange(max(start, 0), end - frame + 1, frame // 2)
        if len(starts) == 0:
            return LOG_EPS
        return float(((cumulative[starts + frame] - cumulative[starts]) / frame).max())

    def _floor(self, squares: Float64Array, onset: int) -> float:
        """Mean square of the quiet moments (a low percentile of 16 ms frames) before the onset."""
        end = onset - self._floor_gap
        count = (end - self._energy) // self._floor_frame  # keep the filter's start-up out
        if count < 1:
            return LOG_EPS
        frames = squares[end - count * self._floor_frame : end].reshape(count, self._floor_frame).mean(axis=1)
        # Digital silence (e.g. before the stream began) is no room: leave it out.
        frames = frames[frames > DIGITAL_SILENCE]
        return max(float(np.percentile(frames, FLOOR_PERCENTILE)), LOG_EPS) if len(frames) else LOG_EPS

    def _voiced_frames(self, x: Float64Array, onset: int, peak_at: int, relevant: float) -> int:
        """Frames within the context either side that are loud enough to matter and periodic at a
        pitch lag (40-400 Hz): normalised autocorrelation of the frame above the threshold, or of
        its part below 1 kHz above a stricter one (jitter blurs the high harmonics of some voices,
        while band-limited noise, such as a dark clap's reverb, correlates more by chance)."""
        w = self.window
        frame, max_lag = self._frame, self._lags[1]
        span = frame + max_lag
        hop = frame // 2
        starts = list(range(onset - self._guard - span, onset - w.context - 1, -hop))
        starts += list(range(peak_at + self._guard, peak_at + w.context - span + 1, hop))
        starts = [s for s in starts if s >= 0 and s + span <= len(x)]
        if not starts:
            return 0
        blocks = np.stack([x[s : s + span] for s in starts])
        blocks = blocks[(blocks[:, :frame] ** 2).mean(axis=1) >= relevant]
        if len(blocks) == 0:
            return 0
        low = sosfilt(self._voicing_band, blocks, axis=1)
        periodic = (self._periodicity(blocks) >= w.voicing_threshold) | (
            self._periodicity(low) >= LOW_BAND_VOICING_THRESHOLD
        )
        return int(np.count_nonzero(periodic))

    def _periodicity(self, blocks: Float64Array) -> Float64Array:
        """Per row: the largest normalised cross-correlation of its first `frame` samples with the
        same length `lag` later, over the pitch lags."""
        frame, max_lag = self._frame, self._lags[1]
        head = np.zeros_like(blocks)
        head[:, :frame] = blocks[:, :frame]
        # cross[l] = sum_k head[k] * block[k + l], for all lags at once
        cross = np.fft.irfft(
            np.conj(np.fft.rfft(head, self._fft)) * np.fft.rfft(blocks, self._fft), self._fft
        )
        lags = np.arange(self._lags[0], max_lag + 1)
        squares = np.concatenate([np.zeros((len(blocks), 1)), np.cumsum(blocks**2, axis=1)], axis=1)
        shifted = squares[:, lags + frame] - squares[:, lags]  # energy of block[l : l + frame]
        nccf = cross[:, lags] / np.sqrt(np.maximum(squares[:, frame : frame + 1] * shifted, LOG_EPS))
        best: Float64Array = nccf.max(axis=1)
        return best
