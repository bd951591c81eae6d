"""Shared fixtures of the offline engine tests: one recognizer, speech synthesized into tmp, a room."""

from __future__ import annotations

import subprocess
import wave
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from by_your_command.audio.pcm import resample
from by_your_command.local_speech.recognizer import OfflineRecognizer


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


@pytest.fixture
def in_room() -> Callable[[np.ndarray, float], np.ndarray]:
    """Audio (16 kHz) as heard across a room: the direct sound plus a diffuse tail decaying 60 dB
    in rt60_s, as loud as the direct sound (the benchmark's room at 0 dB DRR), as float64 scaled
    back to the dry audio's peak."""

    def reverberate(audio: np.ndarray, rt60_s: float) -> np.ndarray:
        time = np.arange(int(rt60_s * 16000)) / 16000
        tail = np.random.default_rng(3).normal(size=len(time)) * np.exp(-6.9 * time / rt60_s)
        tail[:48] = 0.0  # the first reflection 3 ms after the direct sound
        response = tail / np.sqrt(np.sum(tail**2))
        response[0] = 1.0
        wet = np.convolve(audio.astype(np.float64), response)
        return wet * (np.abs(audio).max() / max(np.abs(wet).max(), 1e-9))

    return reverberate
