"""Smart frame forwarding policy: which camera frame to send to agents, and when (no ROS, no pixels).

Agents need a picture when the user starts talking or typing, not a 30 fps stream. The forwarder
keeps the latest frame and forwards it
- at a low baseline rate (`max_video_fps`, 0 = only on triggers),
- immediately on a trigger: voice activity starting, a typed prompt, every Nth voice chunk,
never a frame older than `max_frame_age_ms` and never the same frame twice. Improvement over the
seed: when a trigger finds no fresh frame, the next frame that arrives within `trigger_wait_ms` is
forwarded at once, instead of the agent getting nothing (or a stale frame) for that turn.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Generic, TypeVar

FrameT = TypeVar("FrameT")


@dataclass(frozen=True)
class FrameForwarderParams:
    image_topic: str = field(default="camera/image_raw", metadata={"help": "camera topic (relative)"})
    image_transport: str = field(default="raw", metadata={"help": "raw (sensor_msgs/Image) or compressed"})
    image_reliable: bool = field(
        default=False, metadata={"help": "reliable camera subscription (camera must publish reliable)"}
    )
    max_video_fps: float = field(
        default=0.5, metadata={"help": "baseline forwarding rate; 0 = triggers only"}
    )
    max_frame_age_ms: int = field(default=1000, metadata={"help": "never forward an older frame"})
    trigger_on_voice: bool = field(default=True, metadata={"help": "forward when voice_activity turns True"})
    trigger_on_text: bool = field(default=True, metadata={"help": "forward on every prompt_text"})
    nth_voice_chunk: int = field(
        default=5, metadata={"help": "forward on prompt_voice chunks 0, N, 2N...; 0=off"}
    )
    trigger_wait_ms: int = field(
        default=500, metadata={"help": "a trigger without a fresh frame waits this long"}
    )
    max_width: int = field(default=640, metadata={"help": "wider frames are scaled down (aspect kept)"})
    jpeg_quality: int = field(default=80, metadata={"help": "JPEG quality 1..95 for encoded frames"})
    max_input_pixels: int = field(
        default=4096 * 4096, metadata={"help": "larger frames (declared or raw) are rejected undecoded"}
    )
    max_input_bytes: int = field(
        default=64 * 1024 * 1024,
        metadata={"help": "limit on a frame's data and on its decoded size (bytes)"},
    )
    error_log_interval_s: float = field(
        default=10.0, metadata={"help": "log a rejected frame's kind at most once per interval (counted)"}
    )

    def __post_init__(self) -> None:
        if self.image_transport not in ("raw", "compressed"):
            raise ValueError(f"image_transport must be 'raw' or 'compressed', got {self.image_transport!r}")
        if self.max_video_fps < 0 or self.max_frame_age_ms <= 0 or self.nth_voice_chunk < 0:
            raise ValueError("max_video_fps, nth_voice_chunk must be >= 0 and max_frame_age_ms > 0")
        if self.trigger_wait_ms < 0 or self.max_width < 16 or not 1 <= self.jpeg_quality <= 95:
            raise ValueError("trigger_wait_ms >= 0, max_width >= 16 and jpeg_quality in 1..95 required")
        if self.max_input_pixels < 1 or self.max_input_bytes < 1 or self.error_log_interval_s < 0:
            raise ValueError("max_input_pixels, max_input_bytes must be >= 1, error_log_interval_s >= 0")


@dataclass(frozen=True)
class Forward(Generic[FrameT]):
    frame: FrameT
    reason: str  # baseline | voice | text | voice_chunk (+ "/late" when a waiting trigger was served)
    age_ms: float


@dataclass
class ForwarderStats:
    frames_in: int = 0
    forwarded: dict[str, int] = field(default_factory=dict)
    stale_triggers: int = 0  # a trigger found no fresh frame (and none came within trigger_wait_ms)
    duplicate_triggers: int = 0  # the latest frame had already been forwarded


class ErrorTally:
    """Counts rejected inputs by kind, and rate-limits their log lines: the first of each kind is
    logged at once, then at most one per interval; the rest are counted as unlogged, never lost."""

    def __init__(self, interval_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self._interval_s = interval_s
        self._clock = clock
        self._last_logged: dict[str, float] = {}
        self.counts: dict[str, int] = {}
        self.unlogged = 0

    def record(self, kind: str) -> bool:
        """Count one error of `kind`; True when it should be logged."""
        self.counts[kind] = self.counts.get(kind, 0) + 1
        now = self._clock()
        last = self._last_logged.get(kind)
        if last is not None and now - last < self._interval_s:
            self.unlogged += 1
            return False
        self._last_logged[kind] = now
        return True

    @property
    def total(self) -> int:
        return sum(self.counts.values())


class FrameForwarder(Generic[FrameT]):
    def __init__(self, params: FrameForwarderParams, clock: Callable[[], float] = time.monotonic) -> None:
        self.params = params
        self._clock = clock
        self._latest: FrameT | None = None
        self._latest_at = 0.0
        self._latest_sent = False
        self._last_forward_at = float("-inf")
        self._pending: tuple[str, float] | None = None  # (reason, deadline)
        self.stats = ForwarderStats()

    def on_frame(self, frame: FrameT) -> Forward[FrameT] | None:
        now = self._clock()
        self._latest, self._latest_at, self._latest_sent = frame, now, False
        self.stats.frames_in += 1
        if self._pending is not None:
            reason, deadline = self._pending
            self._pending = None
            if now <= deadline:
                return self._forward(f"{reason}/late", now)
            self.stats.stale_triggers += 1
        fps = self.params.max_video_fps
        if fps > 0 and now - self._last_forward_at >= 1.0 / fps:
            return self._forward("baseline", now)
        return None

    def on_voice_activity(self, active: bool) -> Forward[FrameT] | None:
        return self._trigger("voice") if active and self.params.trigger_on_voice else None

    def on_text(self) -> Forward[FrameT] | None:
        return self._trigger("text") if self.params.trigger_on_text else None

    def on_voice_chunk(self, chunk_sequence: int) -> Forward[FrameT] | None:
        nth = self.params.nth_voice_chunk
        return self._trigger("voice_chunk") if nth and chunk_sequence % nth == 0 else None

    def _trigger(self, reason: str) -> Forward[FrameT] | None:
        now = self._clock()
        fresh = self._latest is not None and (now - self._latest_at) * 1000 <= self.params.max_frame_age_ms
        if fresh and not self._latest_sent:
            return self._forward(reason, now)
        if fresh:
            self.stats.duplicate_triggers += 1  # the agent already has this very frame
        if self.params.trigger_wait_ms > 0:
            self._pending = (reason, now + self.params.trigger_wait_ms / 1000)
        elif not fresh:
            self.stats.stale_triggers += 1
        return None

    def _forward(self, reason: str, now: float) -> Forward[FrameT]:
        assert self._latest is not None
        self._latest_sent = True
        self._last_forward_at = now
        self.stats.forwarded[reason] = self.stats.forwarded.get(reason, 0) + 1
        return Forward(self._latest, reason, (now - self._latest_at) * 1000)
