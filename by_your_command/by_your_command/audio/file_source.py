"""WAV files as a paced stream of 16 kHz mono chunks (the way tests and the demo feed speech)."""

from __future__ import annotations

import wave
from dataclasses import dataclass, field
from pathlib import Path

from by_your_command.audio.pcm import Int16Array, read_wav, resample, to_mono


@dataclass(frozen=True)
class FileSourceConfig:
    files: list[str] = field(
        default_factory=list, metadata={"help": "WAV files (16-bit PCM, any rate/channels), played in order"}
    )
    sample_rate: int = field(default=16000, metadata={"help": "rate of the published audio (Hz)"})
    chunk_samples: int = field(
        default=1024, metadata={"help": "samples per published AudioChunk (as capture)"}
    )
    rate_factor: float = field(default=1.0, metadata={"help": "1.0 = real time, 4.0 = four times faster"})
    loop: bool = field(default=False, metadata={"help": "start again from the first file at the end"})
    min_subscribers: int = field(
        default=1, metadata={"help": "wait for this many subscribers on `audio` before starting"}
    )
    lead_silence_ms: int = field(
        default=0, metadata={"help": "silence published before the first file (lets a graph settle)"}
    )
    wait_for_topic: str = field(
        default="",
        metadata={"help": "also wait for a subscriber on this topic (prompt_voice: an agent listens)"},
    )

    def __post_init__(self) -> None:
        if self.sample_rate <= 0:
            raise ValueError(f"sample_rate must be positive, got {self.sample_rate}")
        if self.chunk_samples <= 0:
            raise ValueError(f"chunk_samples must be positive, got {self.chunk_samples}")
        if not self.rate_factor > 0:
            raise ValueError(f"rate_factor must be > 0, got {self.rate_factor}")
        if self.min_subscribers < 0 or self.lead_silence_ms < 0:
            raise ValueError("min_subscribers and lead_silence_ms must be >= 0")


def load_clip(path: str | Path, sample_rate: int) -> Int16Array:
    """A WAV file as mono int16 at `sample_rate`; raises ValueError/OSError with the file name."""
    try:
        pcm, rate, channels = read_wav(path)
    except (wave.Error, EOFError) as error:
        raise ValueError(f"{path}: not a readable 16-bit PCM WAV file ({error or 'truncated'})") from error
    return resample(to_mono(pcm, channels), rate, sample_rate)


@dataclass(frozen=True)
class Clip:
    name: str  # becomes AudioChunk.stream_id
    samples: Int16Array


@dataclass(frozen=True)
class ScheduledChunk:
    stream_id: str
    samples: Int16Array
    offset_s: float  # stream time of the first sample, from the start of playback


class ChunkSchedule:
    """Which chunks are due at a given time since start; chunk k of the stream is due at
    (samples before it) / (sample_rate * rate_factor). Catches up after a stall instead of drifting."""

    def __init__(self, clips: list[Clip], config: FileSourceConfig) -> None:
        if not any(len(clip.samples) for clip in clips):
            raise ValueError("no audio to play: the files list is empty or every file is empty")
        self._clips = clips
        self._config = config
        self._chunk = config.chunk_samples
        self._clip_index = 0
        self._position = 0  # sample within the current clip
        self._samples_sent = 0
        self.finished = False
        self.passes = 0

    @property
    def samples_sent(self) -> int:
        return self._samples_sent

    def next_due_s(self) -> float:
        """When (seconds since start) the next chunk is due."""
        return self._samples_sent / (self._config.sample_rate * self._config.rate_factor)

    def due(self, elapsed_s: float, max_chunks: int = 1000) -> list[ScheduledChunk]:
        rate = self._config.sample_rate * self._config.rate_factor
        out: list[ScheduledChunk] = []
        while not self.finished and len(out) < max_chunks and self._samples_sent / rate <= elapsed_s:
            clip = self._clips[self._clip_index]
            piece = clip.samples[self._position : self._position + self._chunk]
            if len(piece):
                out.append(ScheduledChunk(clip.name, piece, self._samples_sent / self._config.sample_rate))
            self._samples_sent += len(piece)
            self._position += len(piece)
            if self._position >= len(clip.samples):
                self._next_clip()
        return out

    def _next_clip(self) -> None:
        self._position = 0
        self._clip_index += 1
        if self._clip_index == len(self._clips):
            self.passes += 1
            self._clip_index = 0
            self.finished = not self._config.loop
