"""Double-clap detection on a mono int16 stream; a double clap is the wake gesture.

1. Onsets (audio/clap_onsets.py): the first sample where the 1 ms energy jumps `onset_rise_db`
   above the 20 ms before it, found in exact integer arithmetic so that where block boundaries
   fall never changes what is found.
2. Each onset is measured on a window aligned to it (audio/clap_features.py), once the audio up to
   `speech_context_ms` after it has arrived, and judged: loud enough over the room's noise floor,
   a fast rise, a quiet moment before, a decay after, and nothing voiced around it (speech).
3. Claps pair up: two claps `double_clap_min_gap_ms`..`double_clap_max_gap_ms` apart, alike in
   level and timbre, with no other clap close before the first or after the second (applause and
   clapping to music are rhythms, not the gesture). A much weaker clap soon after a clap is its
   room echo and is ignored. The double clap is reported once nothing can still spoil it.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from by_your_command.audio.clap_features import ClapFeatures, FeatureMeter, FeatureWindow
from by_your_command.audio.clap_onsets import OnsetDetector, StreamHistory
from by_your_command.audio.pcm import Int16Array

ONSET_HOLD_MS = 30.0  # one burst is one onset


@dataclass(frozen=True)
class ClapConfig:
    sample_rate: int = field(default=16000, metadata={"help": "rate the detector runs at (Hz)"})
    onset_rise_db: float = field(
        default=10.0, metadata={"help": "1 ms energy jump over the 20 ms before (dB)"}
    )
    min_peak: float = field(default=0.005, metadata={"help": "min sample peak of a clap (full scale 1)"})
    min_snr_db: float = field(
        default=12.0, metadata={"help": "min clap peak over the room's noise floor (dB)"}
    )
    max_rise_ms: float = field(default=10.0, metadata={"help": "max time from onset to near the peak (ms)"})
    min_decay_db: float = field(
        default=6.0, metadata={"help": "min peak over the mean level 30-100 ms after"}
    )
    min_lead_db: float = field(
        default=12.0, metadata={"help": "min peak over the loudest 10 ms 120-10 ms before"}
    )
    min_tail_db: float = field(
        default=6.0, metadata={"help": "min peak over the loudest 10 ms 30-140 ms after"}
    )
    voicing_threshold: float = field(
        default=0.65, metadata={"help": "normalised autocorrelation (pitch 40-400 Hz) of a voiced frame"}
    )
    speech_context_ms: float = field(
        default=250.0, metadata={"help": "voicing is looked for this far either side"}
    )
    context_level_db: float = field(
        default=30.0, metadata={"help": "context this far below the clap's peak is ignored (dB)"}
    )
    max_voiced_frames: int = field(default=0, metadata={"help": "voiced 30 ms frames allowed around a clap"})
    double_clap_min_gap_ms: float = field(default=150.0, metadata={"help": "min gap between the claps (ms)"})
    double_clap_max_gap_ms: float = field(default=1000.0, metadata={"help": "max gap between the claps (ms)"})
    max_level_difference_db: float = field(
        default=10.0, metadata={"help": "the two claps' levels differ less"}
    )
    max_timbre_difference_octaves: float = field(
        default=1.0, metadata={"help": "the two claps' spectral centroids differ less (octaves)"}
    )
    echo_level_db: float = field(
        default=10.0,
        metadata={"help": "a clap this much weaker than one within the max gap before is its echo"},
    )
    isolation_factor: float = field(
        default=1.25,
        metadata={"help": "no other clap within this many gaps before the first / after the second"},
    )
    enabled: bool = field(default=True, metadata={"help": "publish wake_cmd on a double clap"})

    def __post_init__(self) -> None:
        if not 8000 <= self.sample_rate <= 96000:
            raise ValueError(f"sample_rate must be 8000..96000 Hz, got {self.sample_rate}")
        if not 0 < self.double_clap_min_gap_ms < self.double_clap_max_gap_ms:
            raise ValueError("need 0 < double_clap_min_gap_ms < double_clap_max_gap_ms")
        if self.double_clap_min_gap_ms <= ONSET_HOLD_MS:
            raise ValueError(
                f"double_clap_min_gap_ms must exceed {ONSET_HOLD_MS} ms (one burst is one onset)"
            )
        if self.onset_rise_db <= 0 or self.max_rise_ms <= 0 or self.speech_context_ms <= 0:
            raise ValueError("onset_rise_db, max_rise_ms and speech_context_ms must be positive")
        if not 0 < self.voicing_threshold < 1:
            raise ValueError(f"voicing_threshold must be in (0, 1), got {self.voicing_threshold}")
        if self.max_voiced_frames < 0 or self.isolation_factor < 0:
            raise ValueError("max_voiced_frames and isolation_factor must not be negative")


@dataclass(frozen=True)
class Clap:
    onset: int  # stream sample index of the onset (samples since the stream began)
    time_s: float  # the same, in seconds
    features: ClapFeatures


@dataclass(frozen=True)
class DoubleClap:
    first: Clap
    second: Clap

    @property
    def gap_ms(self) -> float:
        return (self.second.time_s - self.first.time_s) * 1000.0


def rejection(config: ClapConfig, f: ClapFeatures) -> str | None:
    """Why these features are not a clap's (the first test failed), or None for a clap."""
    c = config
    checks = (
        (f.peak >= c.min_peak, "quiet"),
        (f.snr_db >= c.min_snr_db, "near_noise_floor"),
        (f.rise_ms <= c.max_rise_ms, "slow_rise"),
        (f.lead_db >= c.min_lead_db, "sound_before"),
        (f.decay_db >= c.min_decay_db and f.tail_db >= c.min_tail_db, "no_decay"),
        (f.voiced_frames <= c.max_voiced_frames, "voice_around"),
    )
    return next((reason for ok, reason in checks if not ok), None)


class ClapDetector:
    """Feed blocks of any size; returns the claps and double claps found so far, in stream order.

    What is found depends only on the samples, not on how they were cut into blocks. Decisions lag
    the audio: a clap is judged `speech_context_ms` (+ ~30 ms) after it, a double clap once the
    isolation time after its second clap has passed as well.
    """

    def __init__(self, config: ClapConfig) -> None:
        self._config = config
        rate = config.sample_rate
        self._window = FeatureWindow.build(
            rate, config.speech_context_ms, config.context_level_db, config.voicing_threshold
        )
        self._meter = FeatureMeter(self._window)
        self._min_gap = int(config.double_clap_min_gap_ms * rate / 1000)
        self._max_gap = int(config.double_clap_max_gap_ms * rate / 1000)
        self._slice = rate // 10
        self.onsets = 0
        self.claps = 0
        self.echoes = 0
        self.double_claps = 0
        self.rhythms = 0  # double claps spoilt by a clap close before or after them
        self.rejected: Counter[str] = Counter()
        self.reset()

    def reset(self) -> None:
        """Start a new stream (after a gap in the audio); the counters carry on."""
        rate = self._config.sample_rate
        self._history = StreamHistory(self._window.before + self._window.after + self._slice)
        self._onsets = OnsetDetector(rate, self._config.onset_rise_db, ONSET_HOLD_MS)
        self._waiting: list[int] = []  # onsets whose context has not arrived yet
        self._recent: list[Clap] = []  # accepted claps (not echoes) within the last max gap or so
        self._candidate: DoubleClap | None = None
        self._deadline = 0  # the candidate stands if no clap starts up to this sample

    def process(self, pcm: Int16Array) -> list[Clap | DoubleClap]:
        events: list[Clap | DoubleClap] = []
        for start in range(0, len(pcm), self._slice):  # bounded steps: the history stays small
            events += self._process(pcm[start : start + self._slice])
        return events

    def _process(self, pcm: Int16Array) -> list[Clap | DoubleClap]:
        self._history.append(pcm)
        found = self._onsets.process(pcm)
        self.onsets += len(found)
        self._waiting += found
        events: list[Clap | DoubleClap] = []
        decided_until = self._history.end - self._window.after  # every onset before it is judged
        while self._waiting and self._waiting[0] < decided_until:
            onset = self._waiting.pop(0)
            self._confirm(onset, events)  # the candidate may stand before this onset is judged
            segment = self._history.segment(onset - self._window.before, onset + self._window.after)
            features = self._meter.measure(segment)
            reason = rejection(self._config, features)
            if reason is not None:
                self.rejected[reason] += 1
                continue
            events += self._register(Clap(onset, onset / self._config.sample_rate, features))
        self._confirm(decided_until, events)
        return events

    def _confirm(self, decided_until: int, events: list[Clap | DoubleClap]) -> None:
        if self._candidate is not None and decided_until > self._deadline:
            events.append(self._candidate)
            self.double_claps += 1
            self._candidate = None

    def _register(self, clap: Clap) -> list[Clap | DoubleClap]:
        c = self._config
        self._recent = [r for r in self._recent if clap.onset - r.onset <= 2 * self._max_gap]
        previous = self._recent[-1] if self._recent else None
        if previous is not None and clap.onset - previous.onset < self._min_gap:
            return []  # the same clap's flutter or early reflections
        if any(
            clap.onset - r.onset <= self._max_gap
            and clap.features.level_dbfs < r.features.level_dbfs - c.echo_level_db
            for r in self._recent
        ):
            self.echoes += 1
            return []  # the room's echo of an earlier clap
        self.claps += 1
        self._recent.append(clap)
        if self._candidate is not None:  # a third clap too close: a rhythm, not the gesture
            self._candidate = None
            self.rhythms += 1
            return [clap]
        if previous is not None and self._pairs(previous, clap):
            gap = clap.onset - previous.onset
            isolation = min(int(gap * c.isolation_factor), self._max_gap)
            before = self._recent[-3] if len(self._recent) >= 3 else None
            if before is not None and previous.onset - before.onset <= isolation:
                self.rhythms += 1
            else:
                self._candidate = DoubleClap(previous, clap)
                self._deadline = clap.onset + isolation
        return [clap]

    def _pairs(self, first: Clap, second: Clap) -> bool:
        c = self._config
        a, b = first.features, second.features
        return (
            self._min_gap <= second.onset - first.onset <= self._max_gap
            and abs(a.level_dbfs - b.level_dbfs) <= c.max_level_difference_db
            and abs(float(np.log2(max(a.centroid_hz, 1.0) / max(b.centroid_hz, 1.0))))
            <= c.max_timbre_difference_octaves
        )
