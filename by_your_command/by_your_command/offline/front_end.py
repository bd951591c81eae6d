"""Noise suppression before the speech model: a Wiener filter with the noise taken from the
utterance's own quietest frames.

A VAD utterance carries some background before and between the words (pre-roll, pauses). The
noise power spectrum is estimated as the mean over the quietest `noise_fraction` of the STFT frames
(a minimum-statistics estimate: no separate noise recording is needed), and each time-frequency
bin is scaled by the Wiener gain 1 - over_subtraction * noise / power, floored at `floor` so that
no bin is silenced outright (which would add "musical" artefacts). On clean audio the quietest
frames hold almost nothing and the gain is ~1 everywhere: the filter leaves clean speech as it is.
Audio whose quietest frames are nearly as loud as its typical frame (no pause to learn the
background from) is left as it is too.

Measured (tuning voices, white noise at 15 dB SNR): Moonshine's best form was the right one for
47 of 60 commands with the filter, 43 without; clean speech unchanged (docs/offline.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.signal import istft, stft

FloatArray = npt.NDArray[np.float32]
FRAME, HOP = 512, 128  # 32 ms frames every 8 ms at 16 kHz


@dataclass(frozen=True)
class NoiseSuppression:
    enabled: bool = True
    over_subtraction: float = 2.0  # noise power counted this many times (1-3 is usual)
    floor: float = 0.1  # the least gain of any bin
    noise_fraction: float = 0.1  # the quietest share of frames taken as noise
    # Filtered only when the median frame is this much louder than the noise estimate: audio
    # without quieter stretches (no pause, no pre-roll) has no background to learn from.
    min_range_db: float = 6.0

    def __post_init__(self) -> None:
        if self.over_subtraction <= 0 or not 0 < self.floor <= 1 or not 0 < self.noise_fraction < 1:
            raise ValueError("need over_subtraction > 0, 0 < floor <= 1 and 0 < noise_fraction < 1")


def suppress_noise(audio: FloatArray, config: NoiseSuppression, rate: int = 16000) -> FloatArray:
    """The audio with its stationary background reduced; same length. Audio too short for a few
    frames is returned as it is."""
    if not config.enabled or len(audio) < 4 * FRAME:
        return audio
    _, _, spectrum = stft(audio, rate, nperseg=FRAME, noverlap=FRAME - HOP)
    power = np.abs(spectrum) ** 2
    frames = power.shape[1]
    quietest = np.argsort(power.sum(axis=0))[: max(3, int(frames * config.noise_fraction))]
    noise = power[:, quietest].mean(axis=1, keepdims=True)
    if float(np.median(power.sum(axis=0))) < float(noise.sum()) * 10 ** (config.min_range_db / 10):
        return audio
    gain = np.maximum(1.0 - config.over_subtraction * noise / np.maximum(power, 1e-20), config.floor)
    _, filtered = istft(spectrum * gain, rate, nperseg=FRAME, noverlap=FRAME - HOP)
    out = np.zeros_like(audio)
    out[: min(len(audio), len(filtered))] = filtered[: len(audio)]
    return out.astype(np.float32)
