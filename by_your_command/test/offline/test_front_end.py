"""front_end.suppress_noise: stationary background reduced, clean audio left as it is."""

from __future__ import annotations

import numpy as np
import pytest

from by_your_command.offline.front_end import NoiseSuppression, suppress_noise

RATE = 16000


def _tone_in_noise(noise_rms: float) -> tuple[np.ndarray, np.ndarray]:
    """A 0.6 s 440 Hz "word" between 0.3 s of background on each side (like VAD pre-roll)."""
    time = np.arange(int(0.6 * RATE)) / RATE
    speech = np.zeros(int(1.2 * RATE), dtype=np.float32)
    speech[int(0.3 * RATE) : int(0.3 * RATE) + len(time)] = 0.3 * np.sin(2 * np.pi * 440 * time)
    noise = np.random.default_rng(1).normal(0.0, noise_rms, len(speech)).astype(np.float32)
    return speech, speech + noise


@pytest.mark.unit
def test_background_noise_is_reduced_and_the_speech_kept() -> None:
    speech, noisy = _tone_in_noise(0.03)
    cleaned = suppress_noise(noisy, NoiseSuppression())
    assert cleaned.shape == noisy.shape and cleaned.dtype == np.float32
    before = float(np.mean((noisy - speech) ** 2))
    after = float(np.mean((cleaned - speech) ** 2))
    assert after < before / 4  # measured: about a tenth
    pause = slice(0, int(0.25 * RATE))
    assert np.sqrt(np.mean(cleaned[pause] ** 2)) < 0.5 * np.sqrt(np.mean(noisy[pause] ** 2))


@pytest.mark.unit
def test_clean_audio_passes_unchanged_and_disabled_means_untouched() -> None:
    speech, _ = _tone_in_noise(0.0)
    cleaned = suppress_noise(speech, NoiseSuppression())
    np.testing.assert_allclose(cleaned, speech, atol=1e-4)
    _, noisy = _tone_in_noise(0.03)
    assert suppress_noise(noisy, NoiseSuppression(enabled=False)) is noisy
    short = noisy[:1000]
    assert suppress_noise(short, NoiseSuppression()) is short


@pytest.mark.unit
def test_nonsense_settings_are_refused() -> None:
    for bad in ({"over_subtraction": 0.0}, {"floor": 0.0}, {"noise_fraction": 1.0}):
        with pytest.raises(ValueError):
            NoiseSuppression(**bad)  # type: ignore[arg-type]


@pytest.mark.unit
def test_audio_without_a_quieter_stretch_is_not_mistaken_for_noise() -> None:
    steady = (0.3 * np.sin(2 * np.pi * 440 * np.arange(RATE) / RATE)).astype(np.float32)
    assert suppress_noise(steady, NoiseSuppression()) is steady
