"""A synthetic room for echo tests: far-end 'speech' played by a speaker and heard back by the mic.

Shared by the tests and bench/bench_aec.py so both measure the same thing.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from by_your_command.audio.pcm import Int16Array, float_to_int16, read_wav, resample, to_mono

CORPUS = Path(__file__).resolve().parents[1] / "data" / "corpus"
SENTENCES = (
    "The robot turned its head and looked at the door. Could you bring me the red cup from the table, "
    "please? After lunch we will check the battery and then go for a walk in the garden."
)


def recorded_speech(seconds: float, rate: int) -> Int16Array:
    """Real (synthesized) speech, looped to `seconds`: the committed corpus's clean file if it is
    there, else espeak-ng on the spot (a required system package)."""
    clean = sorted(CORPUS.glob("clean*.wav"))
    if clean:
        pcm, source_rate, channels = read_wav(clean[0])
    else:
        espeak = shutil.which("espeak-ng")
        if espeak is None:
            raise RuntimeError("no speech corpus and no espeak-ng: run scripts/bootstrap.sh")
        with tempfile.TemporaryDirectory() as tmp:
            wav = Path(tmp) / "speech.wav"
            subprocess.run([espeak, "-w", str(wav), SENTENCES], check=True, capture_output=True)
            pcm, source_rate, channels = read_wav(wav)
    speech = resample(to_mono(pcm, channels), source_rate, rate)
    repeats = int(np.ceil(seconds * rate / len(speech)))
    return np.tile(speech, repeats)[: int(seconds * rate)]


def speech_like(seconds: float, rate: int, seed: int) -> Int16Array:
    """Noise shaped like speech: a pitched buzz through moving formants, syllable-rate envelope."""
    rng = np.random.default_rng(seed)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    pitch = 120 + 30 * np.sin(2 * np.pi * 0.7 * t)
    phase = 2 * np.pi * np.cumsum(pitch) / rate
    source = np.sign(np.sin(phase)) * 0.5 + 0.3 * rng.standard_normal(n)
    # Two resonators whose centre frequencies wander like formants.
    out = np.zeros(n)
    for centre in (500.0, 1500.0):
        r = 0.97
        w = 2 * np.pi * centre / rate
        out += lfilter([1 - r], [1, -2 * r * np.cos(w), r * r], source)
    syllables = 0.5 + 0.5 * np.sin(2 * np.pi * 4.0 * t) ** 2
    out *= syllables
    out /= np.max(np.abs(out)) + 1e-9
    return float_to_int16(0.5 * out)


@dataclass(frozen=True)
class Room:
    delay_ms: float = 120.0
    gain: float = 0.6  # direct path attenuation
    reverb_ms: float = 150.0  # exponential tail length (time to -60 dB is ~ 3x this)
    reverb_gain: float = 0.25
    noise_dbfs: float = -60.0

    def impulse_response(self, rate: int, seed: int = 0) -> npt.NDArray[np.float64]:
        rng = np.random.default_rng(seed)
        delay = int(self.delay_ms * rate / 1000)
        tail = int(3 * self.reverb_ms * rate / 1000)
        ir = np.zeros(delay + tail + 1)
        ir[delay] = self.gain
        decay = np.exp(-np.arange(tail) / (self.reverb_ms * rate / 1000))
        ir[delay + 1 :] = self.reverb_gain * rng.standard_normal(tail) * decay / np.sqrt(tail / 10)
        return ir

    def echo(self, played: Int16Array, rate: int, seed: int = 0) -> Int16Array:
        """What the mic hears of `played` (same length), plus a faint noise floor."""
        rng = np.random.default_rng(seed + 1)
        far = played.astype(np.float64) / 32768.0
        heard = np.convolve(far, self.impulse_response(rate, seed))[: len(far)]
        heard += 10 ** (self.noise_dbfs / 20) * rng.standard_normal(len(far))
        return float_to_int16(heard)


def energy_db(pcm: Int16Array) -> float:
    power = float(np.mean(np.square(pcm.astype(np.float64)))) + 1e-9
    return 10.0 * float(np.log10(power))
