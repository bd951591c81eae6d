"""front_end: stationary background reduced, clean audio left as it is, the SNR told; reverberation
seen in how slowly sounds die away (fall_time_ms)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from by_your_command.local_speech.acceptance import Acceptance
from by_your_command.local_speech.front_end import (
    NO_BACKGROUND_DB,
    NoiseSuppression,
    fall_time_ms,
    suppress_noise,
)

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


def _words(seed: int = 2) -> np.ndarray:
    """Eight 0.12 s syllables (a tone roughened by noise), each ending abruptly, 0.06 s apart."""
    rng = np.random.default_rng(seed)
    audio = np.zeros(int(1.8 * RATE), dtype=np.float32)
    for start in np.arange(0.1, 1.5, 0.18):
        span = slice(int(start * RATE), int((start + 0.12) * RATE))
        carrier = np.sin(2 * np.pi * 300 * np.arange(span.stop - span.start) / RATE)
        audio[span] = 0.2 * carrier * (1 + 0.3 * rng.normal(size=span.stop - span.start))
    return audio


@pytest.mark.unit
def test_sounds_die_away_slowly_in_a_reverberant_room(
    in_room: Callable[[np.ndarray, float], np.ndarray],
) -> None:
    threshold = Acceptance().reverberant_from_fall_ms
    dry = _words()
    assert 0.0 < fall_time_ms(dry) < threshold / 2
    room = in_room(dry, 0.5)
    assert fall_time_ms(room) > threshold  # a 20 dB fall takes ~167 ms
    assert fall_time_ms(np.repeat(room, 3), 48000) > threshold  # other rates tell the same
    assert fall_time_ms((room * 32767).astype(np.int16)) == fall_time_ms(room)  # only ratios count


@pytest.mark.unit
def test_no_fall_time_is_told_where_nothing_can_fall_far_enough() -> None:
    """Under noise no peak has room to fall 20 dB: 0.0, which tells nothing of a room."""
    noisy = _words() + np.random.default_rng(4).normal(0.0, 0.02, int(1.8 * RATE)).astype(np.float32)
    assert fall_time_ms(noisy) == 0.0
    assert fall_time_ms(_words()[:500]) == 0.0  # too short
    assert fall_time_ms(np.zeros(RATE, dtype=np.float32)) == 0.0  # silence
