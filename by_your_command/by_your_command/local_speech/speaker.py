"""Spoken replies with espeak-ng: text in, mono int16 PCM out, offline.

espeak-ng runs as a subprocess with an argument list (no shell); the text goes through stdin, so
nothing in it can become an option. The text is sanitised and bounded (control characters,
espeak's `[[phoneme]]` input and over-long text never reach it), and the process is killed after
timeout_s. espeak writes a WAV (22.05 kHz) whose header length is bogus over a pipe (0x7fffffff),
so the 44-byte header is checked and skipped, and the audio resampled to sample_rate.
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass

import numpy as np

from by_your_command.audio.pcm import check_sample_rate, resample

MIN_ESPEAK_RATE, MAX_ESPEAK_RATE = 8000, 48000  # espeak-ng writes 22050 Hz (mbrola voices 16000)
WAV_HEADER_BYTES = 44
_VOICE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_+-]{0,39}$")  # en-us, en-us+f3, en-gb-x-rp
_UNSPEAKABLE = re.compile(r"[\x00-\x1f\x7f\[\]<>]+")  # control characters, phoneme and SSML brackets


class SpeechError(RuntimeError):
    """espeak-ng failed, timed out or produced no audio."""


@dataclass(frozen=True)
class SpeakerConfig:
    voice: str = "en-us"
    words_per_minute: int = 165
    sample_rate: int = 16000  # rate of the returned PCM
    max_text_chars: int = 600  # longer text is refused (a reply is a sentence or two)
    timeout_s: float = 5.0
    executable: str = "espeak-ng"

    def __post_init__(self) -> None:
        if not _VOICE.match(self.voice):
            raise ValueError(f"voice {self.voice!r} is not an espeak-ng voice name")
        if not 80 <= self.words_per_minute <= 450:
            raise ValueError("words_per_minute must be within 80..450 (espeak-ng's range)")
        check_sample_rate(self.sample_rate)
        if self.max_text_chars < 1 or self.timeout_s <= 0:
            raise ValueError("max_text_chars and timeout_s must be positive")


def sanitize(text: str, max_chars: int) -> str:
    """The text espeak-ng gets: one line of speakable characters; ValueError when empty or too long."""
    if len(text) > max_chars:
        raise ValueError(f"text of {len(text)} characters is longer than {max_chars}")
    clean = " ".join(_UNSPEAKABLE.sub(" ", text).split())
    if not clean:
        raise ValueError("nothing to say")
    return clean


class Speaker:
    def __init__(self, config: SpeakerConfig | None = None) -> None:
        self.config = config or SpeakerConfig()

    def say(self, text: str) -> tuple[bytes, int]:
        """(mono int16 little-endian PCM, sample rate) of `text` spoken.

        ValueError for text that must not be spoken; SpeechError when espeak-ng fails.
        """
        config = self.config
        clean = sanitize(text, config.max_text_chars)
        command = [
            config.executable,
            "-v",
            config.voice,
            "-s",
            str(config.words_per_minute),
            "--stdout",
            "--stdin",
        ]
        try:
            done = subprocess.run(
                command,
                input=clean.encode("utf-8"),
                capture_output=True,
                timeout=config.timeout_s,
                check=False,
            )
        except subprocess.TimeoutExpired as error:
            raise SpeechError(f"espeak-ng took longer than {config.timeout_s} s") from error
        except OSError as error:
            raise SpeechError(f"cannot run {config.executable}: {error}") from error
        if done.returncode != 0:
            detail = done.stderr.decode("utf-8", "replace").strip()[:200]
            raise SpeechError(f"espeak-ng exited with {done.returncode}: {detail}")
        wav = done.stdout
        if len(wav) <= WAV_HEADER_BYTES or wav[:4] != b"RIFF" or wav[8:12] != b"WAVE":
            raise SpeechError("espeak-ng produced no audio")
        native_rate = int.from_bytes(wav[24:28], "little")
        if not MIN_ESPEAK_RATE <= native_rate <= MAX_ESPEAK_RATE:
            raise SpeechError(f"espeak-ng wrote audio at an unexpected rate ({native_rate} Hz)")
        body = wav[WAV_HEADER_BYTES:]
        samples = np.frombuffer(body[: len(body) // 2 * 2], dtype="<i2").astype(np.int16)
        pcm = resample(samples, native_rate, config.sample_rate)
        return bytes(pcm.astype("<i2").tobytes()), config.sample_rate
