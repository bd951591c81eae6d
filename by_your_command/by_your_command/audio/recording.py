"""Write voice to WAV files: one file per utterance (prompt_voice) or per stream (response_voice)."""

from __future__ import annotations

import logging
import os
import re
import stat
import wave
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

from by_your_command.audio.pcm import Int16Array

log = logging.getLogger(__name__)


def state_dir() -> Path:
    """$XDG_STATE_HOME/by_your_command (~/.local/state/... when unset): what nodes keep across runs."""
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(state) / "by_your_command"


def default_recordings_dir() -> Path:
    """$XDG_STATE_HOME/by_your_command/recordings: private, persistent."""
    return state_dir() / "recordings"


def ensure_private_dir(path: Path) -> Path:
    """Create `path` (0o700) if missing; refuse an existing directory others can write to."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    mode = path.stat().st_mode
    if not stat.S_ISDIR(mode):
        raise NotADirectoryError(f"{path} is not a directory")
    if mode & stat.S_IWOTH:
        raise PermissionError(
            f"refusing to record into world-writable {path}; chmod o-w it or pick another dir"
        )
    return path


@dataclass(frozen=True)
class RecorderConfig:
    output_dir: str = field(
        default="", metadata={"help": "where WAVs go; empty = $XDG_STATE_HOME/by_your_command/recordings"}
    )
    input_mode: str = field(
        default="utterance", metadata={"help": "utterance (prompt_voice) or stream (response_voice)"}
    )
    close_timeout_sec: float = field(
        default=2.0, metadata={"help": "close a file after this long without audio (s)"}
    )

    def __post_init__(self) -> None:
        if self.input_mode not in ("utterance", "stream"):
            raise ValueError(f"input_mode must be 'utterance' or 'stream', got {self.input_mode!r}")
        if not self.close_timeout_sec > 0:
            raise ValueError(f"close_timeout_sec must be > 0, got {self.close_timeout_sec}")

    def directory(self) -> Path:
        return Path(self.output_dir).expanduser() if self.output_dir else default_recordings_dir()


class WavWriter:
    """A WAV file written as audio arrives (the header is patched on close)."""

    def __init__(self, path: Path, sample_rate: int, channels: int) -> None:
        self.path = path
        self.sample_rate = sample_rate
        self.channels = channels
        self.frames = 0
        # 0o600: recordings are the user's voice.
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        self._file = os.fdopen(fd, "wb")
        self._wav = wave.open(self._file, "wb")
        self._wav.setnchannels(channels)
        self._wav.setsampwidth(2)
        self._wav.setframerate(sample_rate)

    def write(self, samples: Int16Array) -> None:
        self._wav.writeframes(np.asarray(samples, dtype="<i2").tobytes())
        self.frames += len(samples) // self.channels

    def close(self) -> None:
        self._wav.close()
        self._file.close()


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]", "_", text)[:64] or "audio"


class _FileRecorder:
    """Shared bookkeeping: the one open file, its key, idle timeout, unique names."""

    def __init__(self, directory: Path, close_timeout_s: float, now: Callable[[], datetime]) -> None:
        self._dir = ensure_private_dir(directory)
        self._timeout = close_timeout_s
        self._now = now
        self._writer: WavWriter | None = None
        self._key: object = None
        self._last_audio = 0.0
        self.closed_files: list[Path] = []

    def _open(self, stem: str, key: object, sample_rate: int, channels: int) -> WavWriter:
        self._key = key
        name = f"{stem}_{self._now():%Y%m%d_%H%M%S}"
        path = self._dir / f"{name}.wav"
        suffix = 1
        while path.exists():
            path = self._dir / f"{name}_{suffix}.wav"
            suffix += 1
        self._writer = WavWriter(path, sample_rate, channels)
        log.info("recording %s (%d Hz)", path.name, sample_rate)
        return self._writer

    def poll(self, monotonic_s: float) -> list[Path]:
        """Close the file when no audio came for close_timeout_sec."""
        if self._writer is not None and monotonic_s - self._last_audio >= self._timeout:
            return self.close()
        return []

    def close(self) -> list[Path]:
        if self._writer is None:
            return []
        self._writer.close()
        path = self._writer.path
        log.info("closed %s (%.2f s)", path.name, self._writer.frames / self._writer.sample_rate)
        self._writer = None
        self._key = None
        self.closed_files.append(path)
        return [path]


class UtteranceRecorder(_FileRecorder):
    """utterance_<id>_<YYYYmmdd_HHMMSS>.wav per utterance; closed on is_utterance_end, new id or timeout."""

    def add(
        self, utterance_id: int, samples: Int16Array, sample_rate: int, is_end: bool, monotonic_s: float
    ) -> list[Path]:
        if sample_rate <= 0:
            raise ValueError(f"utterance {utterance_id}: sample_rate {sample_rate} is not valid")
        closed: list[Path] = []
        key = (utterance_id, sample_rate)
        if self._writer is not None and self._key != key:
            closed += self.close()
        writer = self._writer or self._open(f"utterance_{utterance_id}", key, sample_rate, 1)
        writer.write(samples)
        self._last_audio = monotonic_s
        if is_end:
            closed += self.close()
        return closed


class StreamRecorder(_FileRecorder):
    """One continuous file per stream (e.g. a response on response_voice) at the rate it carries;
    a new file when stream_id, rate or channels change, or after close_timeout_sec of silence."""

    def add(
        self, stream_id: str, samples: Int16Array, sample_rate: int, channels: int, monotonic_s: float
    ) -> list[Path]:
        if sample_rate <= 0 or channels <= 0:
            raise ValueError(f"stream {stream_id!r}: bad format {sample_rate} Hz x {channels} channels")
        closed: list[Path] = []
        key = (stream_id, sample_rate, channels)
        if self._writer is not None and self._key != key:
            closed += self.close()
        writer = self._writer or self._open(f"response_{_safe(stream_id)}", key, sample_rate, channels)
        writer.write(samples)
        self._last_audio = monotonic_s
        return closed
