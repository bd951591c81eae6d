"""Echo control for the microphone stream: half-duplex gate, WebRTC AEC3, or pass-through.

The controller is pure (no ROS): the node hands it microphone blocks stamped with the capture
time of their first sample, reference blocks (what the player actually played) stamped with the
play time of their first sample, and the assistant_speaking state; it returns the blocks to forward.
"""

from __future__ import annotations

import enum
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from by_your_command.audio.pcm import Int16Array, resample, to_mono

if TYPE_CHECKING:
    from livekit.rtc import AudioFrame

_LOG = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
APM_FRAME_MS = 10  # WebRTC's audio processing works on exactly 10 ms frames
APM_RATES = (8000, 16000, 32000, 48000)


class EchoMode(str, enum.Enum):
    GATE = "gate"
    AEC = "aec"
    EXTERNAL = "external"


@dataclass(frozen=True)
class EchoConfig:
    mode: str = field(default="gate", metadata={"help": "gate | aec | external (pass-through)"})
    sample_rate: int = field(default=16000, metadata={"help": "mic rate (aec works at 8/16/32/48 kHz)"})
    gate_tail_ms: int = field(
        default=300, metadata={"help": "gate: keep dropping the mic this long after the assistant stops"}
    )
    aec_stream_delay_ms: int = field(
        default=0,
        metadata={"help": "aec: extra render-to-capture delay hint for AEC3 (it also estimates delay)"},
    )
    aec_reference_wait_ms: int = field(
        default=48,
        metadata={"help": "aec: hold mic audio up to this long for its reference to arrive (adds latency)"},
    )
    aec_noise_suppression: bool = field(default=False, metadata={"help": "aec: also run WebRTC NS"})
    aec_high_pass_filter: bool = field(default=True, metadata={"help": "aec: also run the HPF"})
    reference_history_ms: int = field(
        default=2000, metadata={"help": "aec: how much played audio to keep for alignment"}
    )

    def __post_init__(self) -> None:
        modes = [m.value for m in EchoMode]
        if self.mode not in modes:
            raise ValueError(f"echo mode must be one of {modes}, got {self.mode!r}")
        if self.sample_rate <= 0:
            raise ValueError(f"sample_rate must be positive, got {self.sample_rate}")
        if self.mode == EchoMode.AEC.value and self.sample_rate not in APM_RATES:
            raise ValueError(f"aec mode needs sample_rate in {APM_RATES}, got {self.sample_rate}")
        if self.gate_tail_ms < 0:
            raise ValueError(f"gate_tail_ms must be >= 0, got {self.gate_tail_ms}")
        if self.aec_stream_delay_ms < 0:
            raise ValueError(f"aec_stream_delay_ms must be >= 0, got {self.aec_stream_delay_ms}")
        if self.aec_reference_wait_ms < 0:
            raise ValueError(f"aec_reference_wait_ms must be >= 0, got {self.aec_reference_wait_ms}")
        if self.reference_history_ms < 100:
            raise ValueError(f"reference_history_ms must be >= 100, got {self.reference_history_ms}")

    @property
    def echo_mode(self) -> EchoMode:
        return EchoMode(self.mode)


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
    reference_samples_late: int = 0  # reference that arrived for audio already processed
    aec_frames: int = 0


class HalfDuplexGate:
    """Decides whether the mic is open: closed while the assistant speaks and for a tail after."""

    def __init__(self, tail_ms: int) -> None:
        self._tail_ns = tail_ms * 1_000_000
        self._speaking = False
        self._closed_until_ns = 0

    def set_speaking(self, speaking: bool, now_ns: int) -> None:
        if self._speaking and not speaking:
            self._closed_until_ns = now_ns + self._tail_ns
        self._speaking = speaking

    def is_open(self, now_ns: int) -> bool:
        return not self._speaking and now_ns >= self._closed_until_ns


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
    """WebRTC AEC3 through livekit's AudioProcessingModule, fed one 10 ms frame pair at a time."""

    def __init__(self, sample_rate: int, config: EchoConfig) -> None:
        if sample_rate not in APM_RATES:
            raise ValueError(f"AEC needs a sample rate in {APM_RATES}, got {sample_rate}")
        from livekit import rtc  # heavy native library: only loaded in aec mode

        self._rtc = rtc
        self._rate = sample_rate
        self.frame_samples = sample_rate * APM_FRAME_MS // 1000
        self._delay_ms = config.aec_stream_delay_ms
        self._apm = rtc.AudioProcessingModule(
            echo_cancellation=True,
            noise_suppression=config.aec_noise_suppression,
            high_pass_filter=config.aec_high_pass_filter,
        )

    def process(self, mic: Int16Array, reference: Int16Array) -> Int16Array:
        """Cancel the echo of `reference` (played meanwhile) from one 10 ms `mic` frame."""
        far = self._frame(reference)
        self._apm.process_reverse_stream(far)
        near = self._frame(mic)
        self._apm.set_stream_delay_ms(self._delay_ms)
        self._apm.process_stream(near)
        cleaned: Int16Array = np.frombuffer(near.data, dtype=np.int16).copy()
        return cleaned

    def _frame(self, pcm: Int16Array) -> AudioFrame:
        data = bytearray(np.ascontiguousarray(pcm, dtype=np.int16).tobytes())
        frame: AudioFrame = self._rtc.AudioFrame(data, self._rate, 1, self.frame_samples)
        return frame


class EchoController:
    """Turns the raw mic stream into the stream the VAD may hear."""

    def __init__(self, config: EchoConfig) -> None:
        self.config = config
        self.mode = config.echo_mode
        self.sample_rate = sample_rate = config.sample_rate
        self.stats = EchoStats()
        self._gate = HalfDuplexGate(config.gate_tail_ms)
        self._aec: Aec3 | None = None
        self._reference: ReferenceTimeline | None = None
        self._pending = np.zeros(0, dtype=np.int16)  # mic samples not yet through the AEC
        self._pending_start_ns = 0
        self._wait_samples = config.aec_reference_wait_ms * config.sample_rate // 1000
        if self.mode is EchoMode.AEC:
            self._aec = Aec3(sample_rate, config)
            self._reference = ReferenceTimeline(sample_rate, config.reference_history_ms)

    def set_assistant_speaking(self, speaking: bool, now_ns: int) -> None:
        self._gate.set_speaking(speaking, now_ns)

    def add_reference(self, pcm: Int16Array, sample_rate: int, channels: int, start_ns: int) -> None:
        """Audio the player actually played, starting at `start_ns` (ignored unless mode is aec)."""
        if self._reference is None:
            return
        mono = to_mono(pcm, channels)
        if sample_rate != self.sample_rate:
            mono = resample(mono, sample_rate, self.sample_rate)
        self.stats.reference_blocks += 1
        if self._pending_start_ns and start_ns < self._pending_start_ns:  # that mic audio is gone
            late = (self._pending_start_ns - start_ns) * self.sample_rate // NS_PER_S
            self.stats.reference_samples_late += int(min(late, len(mono)))
        self._reference.add(mono, start_ns)

    def process(self, pcm: Int16Array, start_ns: int, now_ns: int) -> Block | None:
        """One mic block captured from `start_ns` on; returns what to forward (None: nothing now)."""
        self.stats.blocks_in += 1
        if self.mode is EchoMode.EXTERNAL:
            return self._out(Block(np.asarray(pcm, dtype=np.int16), start_ns))
        if self.mode is EchoMode.GATE:
            if not self._gate.is_open(now_ns):
                self.stats.blocks_gated += 1
                self.stats.samples_gated += len(pcm)
                return None
            return self._out(Block(np.asarray(pcm, dtype=np.int16), start_ns))
        return self._cancel(np.asarray(pcm, dtype=np.int16), start_ns)

    def _cancel(self, pcm: Int16Array, start_ns: int) -> Block | None:
        """Run whole 10 ms frames through AEC3 once their reference is in (the player announces
        a block when it starts playing it), or once they have waited aec_reference_wait_ms."""
        if len(self._pending) == 0:
            self._pending_start_ns = start_ns
        self._pending = np.concatenate([self._pending, pcm])
        return self.drain()

    def drain(self) -> Block | None:
        """aec: the mic audio that can go out now (call after add_reference: a reference that
        arrived after its mic audio releases it)."""
        if self._aec is None or self._reference is None or len(self._pending) == 0:
            return None
        step = self._aec.frame_samples
        ready = 0
        while ready + step <= len(self._pending):
            frame_end_ns = self._pending_start_ns + (ready + step) * NS_PER_S // self.sample_rate
            waited = len(self._pending) - (ready + step)
            if self._reference.end_ns < frame_end_ns and waited < self._wait_samples:
                break
            ready += step
        if ready == 0:
            return None
        out = np.empty(ready, dtype=np.int16)
        block_start = self._pending_start_ns
        for offset in range(0, ready, step):
            frame_start = block_start + offset * NS_PER_S // self.sample_rate
            reference = self._reference.read(frame_start, step)
            out[offset : offset + step] = self._aec.process(self._pending[offset : offset + step], reference)
            self.stats.aec_frames += 1
        self._pending = self._pending[ready:].copy()
        self._pending_start_ns = block_start + ready * NS_PER_S // self.sample_rate
        return self._out(Block(out, block_start))

    def _out(self, block: Block) -> Block:
        self.stats.blocks_out += 1
        return block
