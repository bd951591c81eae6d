"""Shared fixtures of the offline engine tests: one recognizer, speech synthesized into tmp."""

from __future__ import annotations

import subprocess
import wave
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from by_your_command.audio.pcm import resample
from by_your_command.offline.recognizer import OfflineRecognizer


@pytest.fixture(scope="module")
def recognizer() -> OfflineRecognizer:
    return OfflineRecognizer()


@pytest.fixture
def synthesize(tmp_path: Path) -> Callable[[str, str], bytes]:
    """16 kHz int16 PCM of `text` spoken by espeak-ng `voice`, through a WAV file in tmp."""

    def speak(text: str, voice: str) -> bytes:
        path = tmp_path / "speech.wav"
        subprocess.run(
            ["espeak-ng", "-v", voice, "-s", "150", "-w", str(path), "--", text], check=True, timeout=30
        )
        with wave.open(str(path)) as file:
            rate = file.getframerate()
            samples = np.frombuffer(file.readframes(file.getnframes()), dtype="<i2").astype(np.int16)
        return bytes(resample(samples, rate, 16000).tobytes())

    return speak
