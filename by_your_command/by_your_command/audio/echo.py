"""Echo control for the microphone stream: half-duplex gate, echo cancellation (our long linear
filter with per-band residual suppression, or WebRTC AEC3), or pass-through.

The controller is pure (no ROS): the node hands it microphone blocks stamped with the capture
time of their first sample, reference blocks (what the player actually played) stamped with the
play time of their first sample, and the assistant_speaking state; it returns the blocks to forward.
"""

from __future__ import annotations

import enum
import logging
import math
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.signal import butter, sosfilt

from by_your_command.audio.echo_gate import EchoGate
from by_your_command.audio.echo_linear import LearnedEcho, LinearAec
from by_your_command.audio.pcm import Int16Array, StampedPcm, StampedResampler, float_to_int16, to_mono

if TYPE_CHECKING:
    from livekit.rtc import AudioFrame

_LOG = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
APM_FRAME_MS = 10  # WebRTC's audio processing works on exactly 10 ms frames
APM_RATES = (8000, 16000, 32000, 48000)
DELAY_PROBE_MS = 600  # probe length for measuring AEC3's own delay (once, at start-up)
DELAY_SEARCH_MS = 50  # AEC3 delays measured 8-17 ms depending on rate and NS
GUARD_REFERENCE_FLOOR_DB = -60.0  # reference quieter than this leaves no echo worth guarding
GUARD_INITIAL_COUPLING_DB = 0.0  # before learning: residual echo as loud as the reference
GUARD_STEP_DB = 0.1  # quantile tracker: step down per 10 ms frame (10 dB/s)
GUARD_QUANTILE = 0.95  # ... and up by STEP * q / (1 - q): settles where 95 % of frames are below
GUARD_AEC_HOLD_MS = 30  # AEC3 lets the room's tail through 40-170 ms after the far end falls silent
GUARD_ATTENUATION = 0.01  # -40 dB for frames the guard holds back


class EchoMode(str, enum.Enum):
    GATE = "gate"
    AEC = "aec"
    EXTERNAL = "external"


class AecEngine(str, enum.Enum):
    LINEAR = "linear"  # our long linear filter + per-band residual suppression: keeps double talk
    WEBRTC = "webrtc"  # WebRTC AEC3 + the whole-frame echo guard: distorts double talk


@dataclass(frozen=True)
class EchoConfig:
    mode: str = field(default="gate", metadata={"help": "gate | aec | external (pass-through)"})
    sample_rate: int = field(default=16000, metadata={"help": "mic rate (aec works at 8/16/32/48 kHz)"})
    gate_tail_ms: int = field(
        default=300, metadata={"help": "gate: keep dropping the mic this long after the assistant stops"}
    )
    aec_engine: str = field(
        default="linear",
        metadata={"help": "aec: linear (long adaptive filter, keeps double talk) | webrtc (AEC3)"},
    )
    aec_filter_ms: int = field(
        default=800,
        metadata={
            "help": "aec linear: echo path span (speaker-to-mic delay + room reverb) the filter models"
        },
    )
    aec_step: float = field(
        default=1.0,
        metadata={"help": "aec linear: share of the Kalman step taken (0-1]: faster vs steadier"},
    )
    aec_double_talk_margin_db: float = field(
        default=6.0,
        metadata={"help": "aec linear: output this far above the echo it leaves = someone talks: freeze"},
    )
    aec_echo_memory: str = field(
        default="auto",
        metadata={
            "help": "aec linear: file that keeps the learned echo path across restarts, so the first "
            "reply is cancelled from its start: auto ($XDG_STATE_HOME/by_your_command/echo_path/"
            "<node>.npz), none, or a path"
        },
    )
    aec_stream_delay_ms: int = field(
        default=0,
        metadata={
            "help": "aec webrtc: extra render-to-capture delay hint for AEC3 (it also estimates delay)"
        },
    )
    aec_reference_wait_ms: int = field(
        default=48,
        metadata={"help": "aec: hold mic audio up to this long for its reference to arrive (adds latency)"},
    )
    aec_noise_suppression: bool = field(default=False, metadata={"help": "aec webrtc: also run WebRTC NS"})
    stamp_tolerance_ms: int = field(
        default=20,
        metadata={"help": "aec: a mic or reference stamp this far off its stream's timeline restarts it"},
    )
    reference_history_ms: int = field(
        default=2000, metadata={"help": "aec: how much played audio to keep for alignment"}
    )
    echo_guard: bool = field(
        default=True,
        metadata={"help": "aec: suppress residual echo (linear: per band, soft; webrtc: mute frames)"},
    )
    echo_guard_margin_db: float = field(
        default=6.0,
        metadata={
            "help": "aec: how far above the residual echo learned so far a band/frame counts as the user"
        },
    )
    echo_guard_floor_db: float = field(
        default=-20.0,
        metadata={"help": "aec linear: the most a band dominated by residual echo is turned down (dB, < 0)"},
    )
    echo_guard_release_db_per_s: float = field(
        default=50.0,
        metadata={
            "help": "aec: how fast the guard's echo estimate decays after the robot (slower than reverb)"
        },
    )
    echo_guard_hangover_ms: int = field(
        default=200, metadata={"help": "aec webrtc: once the user is heard over the robot, pass this long"}
    )

    def __post_init__(self) -> None:
        modes = [m.value for m in EchoMode]
        if self.mode not in modes:
            raise ValueError(f"echo mode must be one of {modes}, got {self.mode!r}")
        if self.sample_rate <= 0:
            raise ValueError(f"sample_rate must be positive, got {self.sample_rate}")
        engines = [e.value for e in AecEngine]
        if self.aec_engine not in engines:
            raise ValueError(f"aec_engine must be one of {engines}, got {self.aec_engine!r}")
        if not 10 <= self.aec_filter_ms <= 2000:
            raise ValueError(f"aec_filter_ms must be in [10, 2000], got {self.aec_filter_ms}")
        if not 0.0 < self.aec_step <= 1.0:
            raise ValueError(f"aec_step must be in (0, 1], got {self.aec_step}")
        if not self.aec_double_talk_margin_db > 0:
            raise ValueError(f"aec_double_talk_margin_db must be > 0, got {self.aec_double_talk_margin_db}")
        if not -60.0 <= self.echo_guard_floor_db < 0.0:
            raise ValueError(f"echo_guard_floor_db must be in [-60, 0), got {self.echo_guard_floor_db}")
        if self.mode == EchoMode.AEC.value and self.sample_rate not in APM_RATES:
            raise ValueError(f"aec mode needs sample_rate in {APM_RATES}, got {self.sample_rate}")
        if self.gate_tail_ms < 0:
            raise ValueError(f"gate_tail_ms must be >= 0, got {self.gate_tail_ms}")
        if not self.aec_echo_memory.strip():
            raise ValueError("aec_echo_memory must be auto, none or a file path, got an empty string")
        if self.aec_stream_delay_ms < 0:
            raise ValueError(f"aec_stream_delay_ms must be >= 0, got {self.aec_stream_delay_ms}")
        if self.aec_reference_wait_ms < 0:
            raise ValueError(f"aec_reference_wait_ms must be >= 0, got {self.aec_reference_wait_ms}")
        if self.stamp_tolerance_ms < 1:
            raise ValueError(f"stamp_tolerance_ms must be >= 1, got {self.stamp_tolerance_ms}")
        if not self.echo_guard_margin_db >= 0:
            raise ValueError(f"echo_guard_margin_db must be >= 0, got {self.echo_guard_margin_db}")
        if self.echo_guard_hangover_ms < 0:
            raise ValueError(f"echo_guard_hangover_ms must be >= 0, got {self.echo_guard_hangover_ms}")
        if not self.echo_guard_release_db_per_s > 0:
            raise ValueError(
                f"echo_guard_release_db_per_s must be > 0, got {self.echo_guard_release_db_per_s}"
            )
        if self.reference_history_ms < 100:
            raise ValueError(f"reference_history_ms must be >= 100, got {self.reference_history_ms}")

    @property
    def echo_mode(self) -> EchoMode:
        return EchoMode(self.mode)

    @property
    def engine(self) -> AecEngine:
        return AecEngine(self.aec_engine)


@dataclass(frozen=True)
class Block:
    """Mono int16 samples and the time of the first one (ns, same clock for mic and reference)."""

    pcm: Int16Array
    start_ns: int


@dataclass
class EchoStats:
    blocks_in: int = 0
    blocks_out: int = 0
    blocks_gated: int = 0
    samples_gated: int = 0
    blocks_rejected: int = 0  # bad input (wrong rate/channels), reported by the caller
    reference_blocks: int = 0
    reference_rejected: int = 0  # bad reference input, reported by the caller
    reference_samples_late: int = 0  # reference that arrived for audio already processed
    reference_restarts: int = 0  # reference stamps off their timeline (a gap or jump back)
    mic_resyncs: int = 0  # mic stamps off the timeline (lost block, jump back): timeline restarted
    aec_frames: int = 0
    aec_frames_unreferenced: int = 0  # released after the full wait, their reference still missing
    guard_frames_muted: int = 0  # aec frames taken down whole as residual echo (guard / suppressor)
    double_talk_frames: int = 0  # aec linear: frames the filter did not adapt on (someone talked)
    path_changes: int = 0  # aec linear: echo path changes relearned (head turned, mic stamps shifted)
    remembered_dropped: int = 0  # aec linear: a remembered echo path that did not fit the room
    remembered_relearned: int = 0  # aec linear: a remembered one whose room changed: relearning it


class ReferenceTimeline:
    """Played audio laid out on the clock, sample by sample, so a mic frame can fetch what
    played at the same moment. Gaps read as silence; old audio is forgotten."""

    def __init__(self, sample_rate: int, history_ms: int) -> None:
        self._rate = sample_rate
        self._capacity = sample_rate * history_ms // 1000
        self._origin_ns: int | None = None  # time of _samples[0]
        self._samples = np.zeros(0, dtype=np.int16)
        self.end_ns = 0  # end of the latest reference received

    def _index(self, time_ns: int) -> int:
        assert self._origin_ns is not None
        return round((time_ns - self._origin_ns) * self._rate / NS_PER_S)

    def add(self, pcm: Int16Array, start_ns: int) -> None:
        if len(pcm) == 0:
            return
        if self._origin_ns is None or start_ns - self._origin_ns > 10 * NS_PER_S:
            self._origin_ns = start_ns
            self._samples = np.zeros(0, dtype=np.int16)
        index = self._index(start_ns)
        if index < 0:  # older than what we keep: keep only the part that overlaps
            pcm = pcm[-index:]
            index = 0
        end = index + len(pcm)
        if end > len(self._samples):
            grown = np.zeros(end, dtype=np.int16)
            grown[: len(self._samples)] = self._samples
            self._samples = grown
        self._samples[index:end] = pcm
        self.end_ns = max(self.end_ns, start_ns + len(pcm) * NS_PER_S // self._rate)
        self._trim()

    def _trim(self) -> None:
        excess = len(self._samples) - self._capacity
        if excess > 0 and self._origin_ns is not None:
            self._samples = self._samples[excess:].copy()
            self._origin_ns += excess * NS_PER_S // self._rate

    def read(self, start_ns: int, count: int) -> Int16Array:
        """`count` samples played from `start_ns` on (zeros where nothing was played)."""
        out = np.zeros(count, dtype=np.int16)
        if self._origin_ns is None:
            return out
        index = self._index(start_ns)
        lo, hi = max(index, 0), min(index + count, len(self._samples))
        if hi > lo:
            out[lo - index : hi - index] = self._samples[lo:hi]
        return out


class Aec3:
    """WebRTC AEC3 through livekit's AudioProcessingModule, fed one 10 ms frame pair at a time.

    AEC3 always runs WebRTC's high-pass filter (~80 Hz) on the mic: its config enforces it, and
    livekit exposes no switch, so there is no `high_pass_filter` option in aec mode. Its output
    lags its input by `delay_samples` (framing inside AEC3, plus NS when on), measured once here.
    """

    def __init__(self, sample_rate: int, config: EchoConfig) -> None:
        if sample_rate not in APM_RATES:
            raise ValueError(f"AEC needs a sample rate in {APM_RATES}, got {sample_rate}")
        from livekit import rtc  # heavy native library: only loaded in aec mode

        self._rtc = rtc
        self._rate = sample_rate
        self._noise_suppression = config.aec_noise_suppression
        self.frame_samples = sample_rate * APM_FRAME_MS // 1000
        self._delay_ms = config.aec_stream_delay_ms
        self._apm = self._new_apm()
        self.delay_samples = self._measure_delay()

    def _new_apm(self) -> Any:
        return self._rtc.AudioProcessingModule(
            echo_cancellation=True, noise_suppression=self._noise_suppression, high_pass_filter=True
        )

    def process(self, mic: Int16Array, reference: Int16Array) -> Int16Array:
        """Cancel the echo of `reference` (played meanwhile) from one 10 ms `mic` frame."""
        return self._process(self._apm, mic, reference)

    def _process(self, apm: Any, mic: Int16Array, reference: Int16Array) -> Int16Array:
        apm.process_reverse_stream(self._frame(reference))
        near = self._frame(mic)
        apm.set_stream_delay_ms(self._delay_ms)
        apm.process_stream(near)
        cleaned: Int16Array = np.frombuffer(near.data, dtype=np.int16).copy()
        return cleaned

    def _frame(self, pcm: Int16Array) -> AudioFrame:
        data = bytearray(np.ascontiguousarray(pcm, dtype=np.int16).tobytes())
        frame: AudioFrame = self._rtc.AudioFrame(data, self._rate, 1, self.frame_samples)
        return frame

    def _measure_delay(self) -> int:
        """Lag (samples) of a throwaway AEC3 with this configuration: the lag of the best match
        between a speech-band noise probe and what comes out (nothing is played meanwhile)."""
        apm = self._new_apm()
        step = self.frame_samples
        rng = np.random.default_rng(0)
        frames = DELAY_PROBE_MS // APM_FRAME_MS
        band = butter(4, [300, 3000], btype="bandpass", fs=self._rate, output="sos")
        probe = float_to_int16(0.3 * sosfilt(band, rng.standard_normal(frames * step)))
        silence = np.zeros(step, dtype=np.int16)
        out = np.concatenate(
            [self._process(apm, probe[k : k + step], silence) for k in range(0, len(probe), step)]
        ).astype(np.float64)
        max_lag = DELAY_SEARCH_MS * self._rate // 1000
        tail = probe[len(probe) // 2 : len(probe) - max_lag].astype(np.float64)
        lo = len(probe) // 2
        scores = [float(np.dot(out[lo + lag : lo + lag + len(tail)], tail)) for lag in range(max_lag)]
        lag = int(np.argmax(scores))
        if scores[lag] <= 0.5 * float(np.dot(tail, tail)):
            _LOG.warning("could not measure the AEC's own delay (no clear match): stamps may be late")
            return 0
        return lag


def frame_level_db(pcm: Int16Array) -> float:
    """Power of a frame in dB relative to full scale (-120 for digital silence)."""
    power = float(np.mean(np.square(pcm, dtype=np.float64))) / (32768.0 * 32768.0)
    return 10.0 * math.log10(power) if power > 1e-12 else -120.0


class QuantileTracker:
    """Running estimate of a quantile of a stream of dB values (steps, no history kept)."""

    def __init__(self, quantile: float, step_db: float, initial_db: float) -> None:
        self.value = initial_db
        self._down = step_db
        self._up = step_db * quantile / (1.0 - quantile)

    def update(self, x: float) -> None:
        self.value += self._up if x > self.value else -self._down


class EchoGuard:
    """Keeps residual echo (what AEC3 leaves of the robot's voice) from reaching the VAD.

    Reference envelope: a peak hold decaying `release_db_per_s`, slower than a room's reverb.
    While it is above GUARD_REFERENCE_FLOOR_DB, an output frame passes only if it is `margin_db`
    above the echo expected at this envelope:
    - while the robot is sounding (reference above the floor in the last GUARD_AEC_HOLD_MS):
      the residual AEC3 leaves, a running GUARD_QUANTILE quantile of output-minus-envelope over
      frames that did not pass (strict at first, GUARD_INITIAL_COUPLING_DB, while AEC3 converges);
    - after that, in the room's tail: AEC3 stops suppressing once the far end is silent, so the
      tail comes through whole; expected is then the raw echo, the same quantile of
      mic-minus-envelope (the speaker-to-mic coupling).
    Once a frame passes, frames pass for `hangover_ms`, so the user's quieter syllables go too.
    """

    def __init__(self, config: EchoConfig, frame_ms: int) -> None:
        self.margin_db = config.echo_guard_margin_db
        self.hangover_frames = config.echo_guard_hangover_ms // frame_ms
        self.release_db = config.echo_guard_release_db_per_s * frame_ms / 1000
        self.hold_frames = GUARD_AEC_HOLD_MS // frame_ms
        self.envelope_db = -120.0
        self.residual = QuantileTracker(GUARD_QUANTILE, GUARD_STEP_DB, GUARD_INITIAL_COUPLING_DB)
        self.coupling = QuantileTracker(GUARD_QUANTILE, GUARD_STEP_DB, GUARD_INITIAL_COUPLING_DB)
        self._quiet_frames = self.hold_frames  # frames since the reference was last above the floor
        self._open_frames = 0

    def passes(self, mic: Int16Array, output: Int16Array, reference: Int16Array) -> bool:
        """Whether this output frame (from `mic`, while `reference` played) may go to the VAD."""
        reference_db = frame_level_db(reference)
        self.envelope_db = max(self.envelope_db - self.release_db, reference_db)
        self._quiet_frames = 0 if reference_db >= GUARD_REFERENCE_FLOOR_DB else self._quiet_frames + 1
        if self.envelope_db < GUARD_REFERENCE_FLOOR_DB:  # nothing (audible) played lately
            self._open_frames = 0
            return True
        relation = frame_level_db(output) - self.envelope_db
        sounding = self._quiet_frames < self.hold_frames
        expected = self.residual.value if sounding else max(self.residual.value, self.coupling.value)
        if relation > expected + self.margin_db:
            self._open_frames = self.hangover_frames + 1
        elif sounding:  # learn how loud echo gets here, from frames echo dominates
            self.residual.update(relation)
            self.coupling.update(frame_level_db(mic) - self.envelope_db)
        if self._open_frames > 0:
            self._open_frames -= 1
            return True
        return False


@dataclass(frozen=True)
class _Segment:
    """APM input samples from `first` on were captured from `start_ns` on (filler: padding)."""

    first: int
    start_ns: int
    filler: bool = False


class EchoController:
    """Turns the raw mic stream into the stream the VAD may hear.

    aec mode: mic and reference are brought to `sample_rate` (stateful resamplers, one per
    stream) and laid on one clock by their stamps. Mic audio goes through the echo engine
    (LinearAec or Aec3) in 10 ms frames: at once while nothing plays or its reference is in, else
    after up to aec_reference_wait_ms. Every output block is stamped with the capture time of
    its first sample (the engine's own delay taken off), and a jump in the mic stamps restarts
    the timeline there instead of shifting it.
    """

    def __init__(self, config: EchoConfig) -> None:
        self.config = config
        self.mode = config.echo_mode
        self.sample_rate = sample_rate = config.sample_rate
        self.stats = EchoStats()
        self._gate = EchoGate(config.gate_tail_ms)
        self._speaking = False
        self._aec: Aec3 | LinearAec | None = None
        self._reference = ReferenceTimeline(sample_rate, config.reference_history_ms)
        tolerance_ns = config.stamp_tolerance_ms * 1_000_000
        self._mic_in = StampedResampler(sample_rate, tolerance_ns)
        self._reference_in = StampedResampler(sample_rate, tolerance_ns)
        self._wait_samples = config.aec_reference_wait_ms * sample_rate // 1000
        self._wait_ns = config.aec_reference_wait_ms * 1_000_000
        self._pending = np.zeros(0, dtype=np.int16)  # mic samples not yet through the AEC
        self._fed = 0  # mic samples fed to AEC3 so far (index of _pending[0])
        self._out_index = 0  # AEC3 output samples so far
        self._segments: deque[_Segment] = deque()
        self._processed_until_ns = 0  # capture time up to which mic audio went through AEC3
        self._guard: EchoGuard | None = None
        self._linear: LinearAec | None = None
        if self.mode is EchoMode.AEC and config.engine is AecEngine.LINEAR:
            if sample_rate not in APM_RATES:
                raise ValueError(f"AEC needs a sample rate in {APM_RATES}, got {sample_rate}")
            self._aec = self._linear = LinearAec(
                sample_rate,
                APM_FRAME_MS,
                filter_ms=config.aec_filter_ms,
                step=config.aec_step,
                double_talk_margin_db=config.aec_double_talk_margin_db,
                suppress_residual=config.echo_guard,
                residual_margin_db=config.echo_guard_margin_db,
                residual_floor_db=config.echo_guard_floor_db,
                tail_decay_db_per_s=config.echo_guard_release_db_per_s,
            )
        elif self.mode is EchoMode.AEC:
            self._aec = Aec3(sample_rate, config)
            if config.echo_guard:
                self._guard = EchoGuard(config, APM_FRAME_MS)

    @property
    def reference(self) -> ReferenceTimeline:
        """The played audio laid out on the clock, at `sample_rate` (aec mode)."""
        return self._reference

    @property
    def echo_path_shape(self) -> tuple[int, int] | None:
        """(partitions, bins) of the linear canceller's echo path; None without one (gate,
        external, webrtc): nothing to remember."""
        return self._linear.canceller.coefficients_shape if self._linear is not None else None

    def learned_echo(self) -> LearnedEcho | None:
        """What the linear canceller learned of the room, once worth remembering (echo_memory)."""
        return self._linear.learned() if self._linear is not None else None

    def start_from_learned(self, learned: LearnedEcho) -> None:
        """Start cancelling where a canceller was before (raises ValueError if it does not fit)."""
        if self._linear is None:
            raise ValueError("only the linear aec engine has an echo path to start from")
        self._linear.start_from(learned)

    @property
    def aec_delay_samples(self) -> int:
        return self._aec.delay_samples if self._aec is not None else 0

    def set_assistant_speaking(self, speaking: bool, now_ns: int) -> None:
        self._gate.set_speaking(speaking, now_ns)
        self._speaking = speaking
        if not speaking:  # the reply is over: the reference resampler's held-back tail is final
            for piece in self._reference_in.flush():
                self._add_reference_piece(piece)

    def add_reference(self, pcm: Int16Array, sample_rate: int, channels: int, start_ns: int) -> None:
        """Audio the player actually played, starting at `start_ns` (ignored unless mode is aec).
        Raises ValueError on bad audio (channels, length, rate)."""
        if self._aec is None:
            return
        mono = to_mono(pcm, channels)
        self.stats.reference_blocks += 1
        for piece in self._reference_in.push(mono, sample_rate, start_ns):
            self._add_reference_piece(piece)
        self.stats.reference_restarts = self._reference_in.restarts

    def _add_reference_piece(self, piece: StampedPcm) -> None:
        if piece.start_ns < self._processed_until_ns:  # that mic audio has gone out without it
            late = (self._processed_until_ns - piece.start_ns) * self.sample_rate // NS_PER_S
            self.stats.reference_samples_late += int(min(late, len(piece.pcm)))
        self._reference.add(piece.pcm, piece.start_ns)

    def process(
        self, pcm: Int16Array, start_ns: int, now_ns: int, sample_rate: int | None = None
    ) -> list[Block]:
        """One mono mic block captured from `start_ns` on (at `sample_rate`, default the
        configured rate); returns the blocks to forward now, in order (often one, maybe none).
        Raises ValueError on a sample rate that cannot be resampled."""
        self.stats.blocks_in += 1
        samples = np.asarray(pcm, dtype=np.int16)
        if self.mode is EchoMode.EXTERNAL:
            return self._out([Block(samples, start_ns)])
        if self.mode is EchoMode.GATE:
            if not self._gate.admits(start_ns, len(samples), sample_rate or self.sample_rate, now_ns):
                self.stats.blocks_gated += 1
                self.stats.samples_gated += len(samples)
                return []
            return self._out([Block(samples, start_ns)])
        released: list[Block] = []
        for piece in self._mic_in.push(samples, sample_rate or self.sample_rate, start_ns):
            if piece.restart:
                released += self._restart_timeline(piece.start_ns)
            self._pending = np.concatenate([self._pending, piece.pcm])
        self.stats.mic_resyncs = self._mic_in.restarts
        return self._out(released + self._release(force=False))

    def drain(self) -> list[Block]:
        """aec: the mic audio that can go out now (call after add_reference or
        set_assistant_speaking: a reference that arrived after its mic audio releases it)."""
        return self._out(self._release(force=False))

    def _restart_timeline(self, start_ns: int) -> list[Block]:
        """The mic stream restarts at `start_ns`: what is pending of the old one goes through
        AEC3 now (its last frame padded with filler) and the new one starts a segment."""
        released: list[Block] = []
        if len(self._pending):
            pad = -len(self._pending) % self.frame_samples
            if pad:
                end = self._fed + len(self._pending)
                self._segments.append(_Segment(end, self._input_time(end), filler=True))
                self._pending = np.concatenate([self._pending, np.zeros(pad, dtype=np.int16)])
            released = self._release(force=True)
        self._segments.append(_Segment(self._fed, start_ns))
        return released

    @property
    def frame_samples(self) -> int:
        return self._aec.frame_samples if self._aec is not None else 0

    def _input_time(self, index: int) -> int:
        """Capture time of AEC3 input sample `index` (continuing the segment it falls in)."""
        segment = self._segments[-1]
        for candidate in reversed(self._segments):
            segment = candidate
            if candidate.first <= index:
                break
        return segment.start_ns + (index - segment.first) * NS_PER_S // self.sample_rate

    def _reference_settled(self, frame_start_ns: int, frame_end_ns: int) -> bool:
        """True when the reference for this mic frame is in, or none is coming: nothing plays
        and the last reference ended more than aec_reference_wait_ms before the frame."""
        if self._reference.end_ns >= frame_end_ns:
            return True
        return not self._speaking and frame_start_ns >= self._reference.end_ns + self._wait_ns

    def _release(self, force: bool) -> list[Block]:
        if self._aec is None or len(self._pending) == 0:
            return []
        step = self._aec.frame_samples
        ready = 0
        while ready + step <= len(self._pending):
            frame_start = self._input_time(self._fed + ready)
            frame_end = frame_start + step * NS_PER_S // self.sample_rate
            waited = len(self._pending) - (ready + step)  # mic samples captured after this frame
            if not force and not self._reference_settled(frame_start, frame_end):
                if waited < self._wait_samples:
                    break
                self.stats.aec_frames_unreferenced += 1
            ready += step
        if ready == 0:
            return []
        processed = np.empty(ready, dtype=np.int16)
        for offset in range(0, ready, step):
            frame_start = self._input_time(self._fed + offset)
            reference = self._reference.read(frame_start, step)
            cleaned = self._aec.process(self._pending[offset : offset + step], reference)
            mic = self._pending[offset : offset + step]
            if self._guard is not None and not self._guard.passes(mic, cleaned, reference):
                cleaned = (cleaned * GUARD_ATTENUATION).astype(np.int16)
                self.stats.guard_frames_muted += 1
            processed[offset : offset + step] = cleaned
            self.stats.aec_frames += 1
        if self._linear is not None:
            self.stats.double_talk_frames = self._linear.canceller.stats.double_talk_blocks
            self.stats.path_changes = self._linear.canceller.stats.path_changes
            self.stats.remembered_dropped = self._linear.canceller.stats.remembered_dropped
            self.stats.remembered_relearned = self._linear.canceller.stats.remembered_relearned
            if self._linear.suppressor is not None:
                self.stats.guard_frames_muted = self._linear.suppressor.frames_muted
        self._pending = self._pending[ready:].copy()
        self._fed += ready
        self._processed_until_ns = self._input_time(self._fed)
        return self._stamp_output(processed)

    def _stamp_output(self, processed: Int16Array) -> list[Block]:
        """Cut AEC3 output into blocks stamped with the capture time of their first sample:
        output sample i is input sample i - delay; AEC3's start-up silence and filler are dropped."""
        assert self._aec is not None
        delay = self._aec.delay_samples
        first_input = self._out_index - delay
        self._out_index += len(processed)
        blocks: list[Block] = []
        segments = list(self._segments)
        for k, segment in enumerate(segments):
            end = segments[k + 1].first if k + 1 < len(segments) else None
            lo = max(segment.first, first_input)
            hi = first_input + len(processed) if end is None else min(end, first_input + len(processed))
            if hi <= lo or segment.filler:
                continue
            start_ns = segment.start_ns + (lo - segment.first) * NS_PER_S // self.sample_rate
            blocks.append(Block(processed[lo - first_input : hi - first_input].copy(), start_ns))
        # Forget segments whose samples have all come out (keep the last: it goes on).
        while len(self._segments) > 1 and self._segments[1].first <= self._out_index - delay:
            self._segments.popleft()
        return blocks

    def _out(self, blocks: list[Block]) -> list[Block]:
        self.stats.blocks_out += len(blocks)
        return blocks
