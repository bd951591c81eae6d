"""front_end.suppress_noise: stationary background reduced, clean audio left as it is, the SNR told."""

from __future__ import annotations

import math

import numpy as np
import pytest

from by_your_command.offline.front_end import NO_BACKGROUND_DB, NoiseSuppression, suppress_noise

RATE = 16000


def _tone_in_noise(noise_rms: float, word_s: float = 0.6) -> tuple[np.ndarray, np.ndarray]:
    """A 440 Hz "word" after 0.3 s of background, 0.3 s or more after it (like VAD pre-roll)."""
    time = np.arange(int(word_s * RATE)) / RATE
    speech = np.zeros(int(1.2 * RATE), dtype=np.float32)
    speech[int(0.3 * RATE) : int(0.3 * RATE) + len(time)] = 0.3 * np.sin(2 * np.pi * 440 * time)
    noise = np.random.default_rng(1).normal(0.0, noise_rms, len(speech)).astype(np.float32)
    return speech, speech + noise


@pytest.mark.unit
def test_background_noise_is_reduced_and_the_speech_kept() -> None:
    speech, noisy = _tone_in_noise(0.03)
    result = suppress_noise(noisy, NoiseSuppression())
    cleaned = result.audio
    assert cleaned.shape == noisy.shape and cleaned.dtype == np.float32
    before = float(np.mean((noisy - speech) ** 2))
    after = float(np.mean((cleaned - speech) ** 2))
    assert after < before / 4  # measured: about a tenth
    pause = slice(0, int(0.25 * RATE))
    assert np.sqrt(np.mean(cleaned[pause] ** 2)) < 0.5 * np.sqrt(np.mean(noisy[pause] ** 2))
    # The tone's power (0.045) over the noise's (0.0009 over 1.2 s of 16 kHz): 17 dB.
    assert 14 < result.snr_db < 20


@pytest.mark.unit
def test_a_short_word_in_long_background_is_filtered() -> None:
    """Most frames are background here, so a typical frame is no louder than the noise estimate;
    the loud frames are, and they are what tells that there is something to keep."""
    speech, noisy = _tone_in_noise(0.03, word_s=0.15)
    cleaned = suppress_noise(noisy, NoiseSuppression()).audio
    assert float(np.mean((cleaned - speech) ** 2)) < float(np.mean((noisy - speech) ** 2)) / 4


@pytest.mark.unit
def test_clean_audio_passes_unchanged_and_disabled_means_untouched() -> None:
    speech, _ = _tone_in_noise(0.0)
    result = suppress_noise(speech, NoiseSuppression())
    np.testing.assert_allclose(result.audio, speech, atol=1e-4)
    assert result.snr_db == NO_BACKGROUND_DB
    _, noisy = _tone_in_noise(0.03)
    disabled = suppress_noise(noisy, NoiseSuppression(enabled=False))
    assert disabled.audio is noisy and 14 < disabled.snr_db < 20  # still measured
    short = noisy[:1000]
    assert suppress_noise(short, NoiseSuppression()).audio is short


@pytest.mark.unit
def test_nonsense_settings_are_refused() -> None:
    for bad in (
        {"smoothing": 1.0},
        {"smoothing": -0.1},
        {"floor": 0.0},
        {"noise_fraction": 1.0},
        {"min_range_db": math.nan},
    ):
        with pytest.raises(ValueError):
            NoiseSuppression(**bad)  # type: ignore[arg-type]


@pytest.mark.unit
def test_audio_without_a_quieter_stretch_is_not_mistaken_for_noise() -> None:
    steady = (0.3 * np.sin(2 * np.pi * 440 * np.arange(RATE) / RATE)).astype(np.float32)
    assert suppress_noise(steady, NoiseSuppression()).audio is steady
