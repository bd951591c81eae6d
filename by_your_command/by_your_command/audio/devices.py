"""PortAudio devices: listing, choosing by index or name, and a capture stream with a minimal
callback (copy into a bounded queue, count overruns). Also the dead-input detector."""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from by_your_command.audio.pcm import Int16Array, to_mono

_LOG = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000


class AudioDeviceError(RuntimeError):
    """A sound device could not be found or opened; the message says which and why."""


class DeviceNotFoundError(AudioDeviceError):
    """No usable device: the message names what was looked for and what exists."""


@dataclass(frozen=True)
class DeviceInfo:
    index: int
    name: str
    max_input_channels: int
    max_output_channels: int
    default_samplerate: float
    hostapi: int = 0

    @classmethod
    def from_portaudio(cls, index: int, info: Mapping[str, Any]) -> DeviceInfo:
        """From one entry of sounddevice.query_devices()."""
        return cls(
            index=int(info.get("index", index)),
            name=str(info["name"]),
            max_input_channels=int(info.get("max_input_channels", 0)),
            max_output_channels=int(info.get("max_output_channels", 0)),
            default_samplerate=float(info.get("default_samplerate", 0.0)),
            hostapi=int(info.get("hostapi", 0)),
        )

    def has(self, direction: str) -> bool:
        return (self.max_input_channels if direction == "input" else self.max_output_channels) > 0


def parse_devices(raw: Sequence[Mapping[str, Any]]) -> list[DeviceInfo]:
    return [DeviceInfo.from_portaudio(i, info) for i, info in enumerate(raw)]


def format_devices(devices: Sequence[DeviceInfo], default_input: int = -1, default_output: int = -1) -> str:
    """A table like `python -m sounddevice`: index, in/out channels, default rate, name."""
    if not devices:
        return "no audio devices found (PortAudio sees none)"
    lines = ["  idx  in out     rate  name"]
    for d in devices:
        mark = ">" if d.index == default_input else ("<" if d.index == default_output else " ")
        lines.append(
            f"{mark}{d.index:4d} {d.max_input_channels:3d} {d.max_output_channels:3d} "
            f"{d.default_samplerate:8.0f}  {d.name}"
        )
    lines.append("  (> default input, < default output)")
    return "\n".join(lines)


def select_device(
    devices: Sequence[DeviceInfo], selector: str, direction: str = "input", default: int = -1
) -> DeviceInfo:
    """The device named by `selector`: '' = the default, digits = an index, else a case-insensitive
    name substring (the first match with channels in `direction`)."""
    if direction not in ("input", "output"):
        raise ValueError(f"direction must be 'input' or 'output', got {direction!r}")
    usable = [d for d in devices if d.has(direction)]
    listing = ", ".join(f"{d.index}: {d.name}" for d in usable) or "none"
    selector = selector.strip()
    if not selector:
        wanted = f"default {direction} device"
        match = next((d for d in usable if d.index == default), None)
        if match is None and default < 0 and usable:
            match = usable[0]
    elif selector.lstrip("-").isdigit():
        wanted = f"{direction} device index {selector}"
        match = next((d for d in usable if d.index == int(selector)), None)
    else:
        wanted = f"{direction} device whose name contains {selector!r}"
        match = next((d for d in usable if selector.lower() in d.name.lower()), None)
    if match is None:
        raise DeviceNotFoundError(
            f"found no {wanted}; {direction} devices PortAudio sees: {listing} "
            "(list them with `audio_capture --list-devices`)"
        )
    return match


@dataclass(frozen=True)
class CaptureConfig:
    device: str = field(default="", metadata={"help": "input device index or name substring; '' = default"})
    sample_rate: int = field(default=16000, metadata={"help": "capture rate (Hz)"})
    channels: int = field(default=1, metadata={"help": "channels to open; published mixed to mono"})
    chunk: int = field(
        default=1024,
        metadata={"help": "samples per published chunk (1024 = 64 ms at 16 kHz: half the messages of 512)"},
    )
    queue_chunks: int = field(default=64, metadata={"help": "chunks buffered between callback and node"})
    dead_input_s: float = field(default=3.0, metadata={"help": "warn after this long of exact zeros"})
    list_devices: bool = field(default=False, metadata={"help": "log the device list at startup"})

    def __post_init__(self) -> None:
        if self.sample_rate <= 0 or self.channels < 1 or self.chunk < 1 or self.queue_chunks < 1:
            raise ValueError(
                "sample_rate, channels, chunk and queue_chunks must be positive; got "
                f"{self.sample_rate}, {self.channels}, {self.chunk}, {self.queue_chunks}"
            )
        if self.dead_input_s <= 0:
            raise ValueError(f"dead_input_s must be positive, got {self.dead_input_s}")


class DeadInputDetector:
    """Says once when the input has been exactly zero for `seconds` (a muted or dead device), and
    once when it comes back."""

    def __init__(self, sample_rate: int, seconds: float) -> None:
        self._limit = int(sample_rate * seconds)
        self._zeros = 0
        self.dead = False

    def update(self, pcm: Int16Array) -> str | None:
        """Feed a block; returns 'dead' or 'alive' when the state changes, else None."""
        if len(pcm) and not np.any(pcm):
            self._zeros += len(pcm)
            if not self.dead and self._zeros >= self._limit:
                self.dead = True
                return "dead"
            return None
        if len(pcm):
            self._zeros = 0
            if self.dead:
                self.dead = False
                return "alive"
        return None


@dataclass(frozen=True)
class CapturedChunk:
    pcm: Int16Array  # interleaved, as captured
    start_ns: int  # capture time of the first sample (time.time_ns clock)


class CaptureQueue:
    """The only thing the PortAudio callback touches: copy the block, stamp it, queue it."""

    def __init__(self, max_chunks: int) -> None:
        self._queue: queue.Queue[CapturedChunk] = queue.Queue(maxsize=max_chunks)
        self.overruns = 0  # chunks lost because the consumer fell behind
        self.device_overflows = 0  # PortAudio reported input overflow
        self.first_callback = threading.Event()

    def push(self, data: Any, start_ns: int, overflowed: bool = False) -> None:
        if overflowed:
            self.device_overflows += 1
        self.first_callback.set()
        try:
            self._queue.put_nowait(CapturedChunk(np.array(data, dtype=np.int16).reshape(-1), start_ns))
        except queue.Full:
            self.overruns += 1

    def get(self, timeout: float) -> CapturedChunk | None:
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None


@dataclass(frozen=True)
class CaptureEvent:
    level: str  # "info" | "warning"
    text: str


class CaptureMonitor:
    """Turns captured chunks into mono blocks and says what the operator should know: first audio
    ("ready"), a dead input, its recovery, and lost chunks."""

    def __init__(self, config: CaptureConfig, channels: int, captured: CaptureQueue) -> None:
        self._config = config
        self._channels = channels
        self._captured = captured
        self._dead = DeadInputDetector(config.sample_rate, config.dead_input_s)
        self._ready = False
        self._reported_losses = 0

    def process(self, chunk: CapturedChunk) -> tuple[Int16Array, list[CaptureEvent]]:
        events: list[CaptureEvent] = []
        if not self._ready:
            self._ready = True
            events.append(CaptureEvent("info", "ready: audio is flowing"))
        mono = to_mono(chunk.pcm, self._channels)
        change = self._dead.update(mono)
        if change == "dead":
            events.append(
                CaptureEvent(
                    "warning",
                    f"input has been exact digital silence for {self._config.dead_input_s:.1f} s: the "
                    "device is muted, disconnected or not the microphone you meant (see --list-devices)",
                )
            )
        elif change == "alive":
            events.append(CaptureEvent("info", "input is live again"))
        losses = self._captured.overruns + self._captured.device_overflows
        if losses > self._reported_losses:
            self._reported_losses = losses
            events.append(
                CaptureEvent(
                    "warning",
                    f"{losses} audio chunks lost so far ({self._captured.overruns} behind the node, "
                    f"{self._captured.device_overflows} device overflows)",
                )
            )
        return mono, events


def query_devices() -> tuple[list[DeviceInfo], int, int]:
    """(devices, default input index, default output index) as PortAudio sees them."""
    import sounddevice as sd

    raw = sd.query_devices()
    defaults = list(sd.default.device)
    return parse_devices(list(raw)), int(defaults[0]), int(defaults[1])


class CaptureStream:
    """An open PortAudio input stream feeding a CaptureQueue; kept open for the owner's lifetime."""

    def __init__(self, config: CaptureConfig, device: DeviceInfo, sink: CaptureQueue) -> None:
        import sounddevice as sd

        self.device = device
        self._sink = sink
        self._chunk_ns = config.chunk * NS_PER_S // config.sample_rate

        def callback(indata: Any, frames: int, time_info: Any, status: Any) -> None:
            # Keep it minimal: PortAudio calls this on a realtime thread.
            now = time.time_ns()
            lag = float(time_info.currentTime - time_info.inputBufferAdcTime) if time_info else 0.0
            start = now - int(lag * NS_PER_S) if 0.0 < lag < 1.0 else now - self._chunk_ns
            sink.push(indata, start, bool(status and status.input_overflow))

        try:
            self._stream: Any = sd.InputStream(
                samplerate=config.sample_rate,
                channels=min(config.channels, device.max_input_channels),
                dtype="int16",
                device=device.index,
                blocksize=config.chunk,
                callback=callback,
            )
            self._stream.start()
        except sd.PortAudioError as error:
            raise AudioDeviceError(
                f"cannot open input device {device.index} '{device.name}' at {config.sample_rate} Hz: {error}"
            ) from error
        self.channels = int(self._stream.channels)

    def close(self) -> None:
        self._stream.abort()
        self._stream.close()
