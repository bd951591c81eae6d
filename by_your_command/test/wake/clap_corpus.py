"""A clap corpus generated in code from a seed (nothing binary committed): double claps with several
timbres, rooms, distances and background noises, and speech (espeak-ng) with and without noise.

Shared by the tests in test/wake and by bench/bench_clap.py, so both measure the same thing.
There are two disjoint sets so thresholds are not tuned on what is measured: TUNING (seeds,
voices and sentences the detector was tuned on) and HELD_OUT (other seeds, voices and sentences;
the figures in the docs come from it).
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.signal import butter, lfilter, sosfilt

from by_your_command.audio.pcm import Int16Array, float_to_int16, read_wav, resample, to_mono

RATE = 16000
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Timbre:
    """A hand clap: band-limited noise, rising in `attack_ms`, decaying with time constant `decay_ms`."""

    name: str
    low_hz: float
    high_hz: float
    attack_ms: float
    decay_ms: float


TIMBRES = (
    Timbre("bright", 1500.0, 6500.0, 0.5, 4.0),  # flat palms: zero-crossing rate ~0.4
    Timbre("mid", 800.0, 3500.0, 1.0, 6.0),
    Timbre("dark", 350.0, 1800.0, 1.0, 8.0),  # cupped hands: zero-crossing rate ~0.1-0.2
    Timbre("deep", 250.0, 1100.0, 1.5, 12.0),  # very cupped, slow decay
)


@dataclass(frozen=True)
class RoomSpec:
    rt60_s: float  # reverberation time (to -60 dB)
    direct_to_reverb_db: float  # falls with distance


def clap_burst(rng: np.random.Generator, timbre: Timbre, rate: int = RATE) -> FloatArray:
    """One dry clap, peak 1, ~8 time constants long."""
    n = int(8 * timbre.decay_ms * rate / 1000) + 1
    t = np.arange(n) / rate
    noise = rng.standard_normal(n + 256)
    sos = butter(
        4, [timbre.low_hz, min(timbre.high_hz, 0.45 * rate)], btype="bandpass", fs=rate, output="sos"
    )
    band = sosfilt(sos, noise)[256:]  # drop the filter's start-up
    attack = np.clip(t / (timbre.attack_ms / 1000), 0.0, 1.0)
    burst: FloatArray = band * attack * np.exp(-t / (timbre.decay_ms / 1000))
    burst /= np.abs(burst).max()
    return burst


def room_impulse_response(rng: np.random.Generator, room: RoomSpec, rate: int = RATE) -> FloatArray:
    """Direct path, a few early reflections, then an exponentially decaying diffuse tail whose energy
    relative to the direct path is `direct_to_reverb_db` below it."""
    length = int(min(room.rt60_s, 1.2) * rate)
    ir = np.zeros(length)
    ir[0] = 1.0
    for _ in range(4):  # early reflections 3-25 ms later, weaker than the direct sound
        at = int(rng.uniform(0.003, 0.025) * rate)
        ir[at] += rng.uniform(-0.5, 0.5)
    start = int(0.005 * rate)
    t = np.arange(length - start) / rate
    tail = rng.standard_normal(length - start) * np.exp(-6.9 * t / room.rt60_s)
    # Energy of the tail = energy of the direct path (1) / 10^(drr/10).
    tail *= np.sqrt(10 ** (-room.direct_to_reverb_db / 10) / np.sum(tail**2))
    ir[start:] += tail
    return ir


def background_noise(rng: np.random.Generator, kind: str, level_dbfs: float, n: int) -> FloatArray:
    """Room noise at an RMS level: white, pink, brown (rumble) or a fan (hum + broadband)."""
    white = rng.standard_normal(n)
    if kind == "white":
        noise = white
    elif kind == "pink":  # Paul Kellet's economy pink filter
        noise = lfilter(
            [0.049922035, -0.095993537, 0.050612699, -0.004408786],
            [1, -2.494956002, 2.017265875, -0.522189400],
            white,
        )
    elif kind == "brown":
        noise = lfilter([1.0], [1.0, -0.995], white)
    elif kind == "fan":
        t = np.arange(n) / RATE
        hum = sum(
            np.sin(2 * np.pi * f * t + rng.uniform(0, 6.3)) / k for k, f in enumerate((100, 200, 300), 1)
        )
        noise = lfilter([1.0], [1.0, -0.9], white) * 0.3 + hum
    else:
        raise ValueError(f"unknown noise kind {kind!r}")
    noise = noise - noise.mean()
    result: FloatArray = noise * (10 ** (level_dbfs / 20) / (np.sqrt(np.mean(noise**2)) + 1e-12))
    return result


NOISE_KINDS = ("white", "pink", "brown", "fan")


@dataclass(frozen=True)
class ClapScene:
    """Audio holding claps at known places (the onsets, in samples) and what made them."""

    pcm: Int16Array
    clap_samples: tuple[int, ...]
    description: str

    @property
    def seconds(self) -> float:
        return len(self.pcm) / RATE


def place_claps(
    rng: np.random.Generator,
    times_s: Sequence[float],
    seconds: float,
    timbre: Timbre,
    room: RoomSpec,
    peak: float,
    noise_kind: str = "pink",
    noise_dbfs: float = -65.0,
    level_jitter_db: float = 3.0,
    bed: FloatArray | None = None,
) -> ClapScene:
    """Claps at `times_s` in one room; the first clap's (reverberant) peak is `peak`, the others
    vary by up to `level_jitter_db` and in band edges by ~10 % (two claps are never identical).
    `bed` (float, full scale 1) is mixed underneath, e.g. speech."""
    n = int(seconds * RATE)
    audio = background_noise(rng, noise_kind, noise_dbfs, n)
    if bed is not None:
        audio[: min(n, len(bed))] += bed[:n]
    ir = room_impulse_response(rng, room)
    samples = []
    for index, at_s in enumerate(times_s):
        jitter = rng.uniform(0.9, 1.1)
        varied = Timbre(
            timbre.name, timbre.low_hz * jitter, timbre.high_hz * jitter, timbre.attack_ms, timbre.decay_ms
        )
        wet = np.convolve(clap_burst(rng, varied), ir)
        gain = peak if index == 0 else peak * 10 ** (rng.uniform(-level_jitter_db, level_jitter_db) / 20)
        wet *= gain / np.abs(wet).max()
        at = int(at_s * RATE)
        end = min(n, at + len(wet))
        audio[at:end] += wet[: end - at]
        samples.append(at)
    description = (
        f"{timbre.name} rt60={room.rt60_s:.2f}s drr={room.direct_to_reverb_db:+.0f}dB peak={peak:.3f} "
        f"{noise_kind}@{noise_dbfs:.0f}dBFS claps={','.join(f'{t:.3f}' for t in times_s)}"
    )
    return ClapScene(float_to_int16(audio), tuple(samples), description)


def double_clap_scenes(seed: int, count: int) -> list[ClapScene]:
    """`count` double claps, each in its own random room, distance, timbre and noise; gaps 200-900 ms.

    Distance sets both the level (peak 0.02-0.6, log-uniform) and the direct-to-reverb ratio (far =
    more reverb); rooms have RT60 0.2-0.9 s. The noise stays >= 24 dB below the clap's peak (a clap
    quieter than that in its room is not something to wake on)."""
    rng = np.random.default_rng(seed)
    scenes = []
    for index in range(count):
        timbre = TIMBRES[index % len(TIMBRES)]
        nearness = rng.uniform(0.0, 1.0)  # 0 = far, 1 = close
        peak = float(0.02 * (0.6 / 0.02) ** nearness)
        room = RoomSpec(
            rt60_s=float(rng.uniform(0.2, 0.9)), direct_to_reverb_db=float(-4.0 + 16.0 * nearness)
        )
        noise_kind = NOISE_KINDS[int(rng.integers(len(NOISE_KINDS)))]
        noise_dbfs = float(min(rng.uniform(-75.0, -50.0), 20 * np.log10(peak) - 24.0))
        first = float(rng.uniform(0.8, 1.5))
        gap = float(rng.uniform(0.2, 0.9))
        scenes.append(
            place_claps(
                rng, [first, first + gap], first + gap + 1.8, timbre, room, peak, noise_kind, noise_dbfs
            )
        )
    return scenes


# --- speech -------------------------------------------------------------------------------------

# Sentences full of plosives and clicks ("t", "k", "p", "ch"), the sounds that look like claps.
TUNING_SENTENCES = (
    "I can't sleep at night.",
    "What time is it?",
    "I stopped to look up at the stars.",
    "Take the cup to the kitchen and put it back.",
    "Pick up that pack of cards quickly.",
    "Stop! Don't touch the hot pot.",
    "Could you check the top shelf, please?",
    "The cat jumped to catch the bat.",
    "Tick, tock, the clock kept ticking.",
    "Put the book back on the desk.",
    "Keep the kettle in the kitchen.",
    "Kick it to the captain, quick!",
    "Tap twice to start, then stop.",
    "Patrick packed a pink backpack.",
    "Go get it. Quick. Quick. Come back.",
    "That's it, that's it exactly.",
)
HELD_OUT_SENTENCES = (
    "Can you tell me what the weather will be tomorrow?",
    "Please pick the pepper pot up from the table.",
    "Tap it, tap it, tap it, then stop and wait.",
    "Peter Piper picked a peck of pickled peppers.",
    "Check the clock; it's quarter to ten.",
    "Take a deep breath and count to ten.",
    "The kite got caught at the top of the oak tree.",
    "Stop, stop, stop! Put that cup down.",
    "Ticket, pocket, packet, bucket, jacket.",
    "Don't cut the cake yet, Kate.",
    "Keep calm and carry on talking.",
    "Tom kept two cats and a pet parrot.",
    "Click the top button, then the back button.",
    "Quit it! Quit tapping the desk!",
    "Pack the tent, the pots and the tape.",
    "It took a couple of tries to get it right.",
)
TUNING_VOICES = ("en-us+m3", "en-gb+f2", "en-gb-scotland+m1", "en-029+f4", "en-us+klatt")
HELD_OUT_VOICES = (
    "en-us-nyc+m5",
    "en-gb-x-rp+f3",
    "en-gb-x-gbclan+m7",
    "en-us+f5",
    "en-gb-x-gbcwmd+m2",
    "en-us+klatt4",
)


@dataclass(frozen=True)
class CorpusSet:
    name: str
    clap_seed: int
    speech_seed: int
    sentences: tuple[str, ...]
    voices: tuple[str, ...]


TUNING = CorpusSet("tuning", clap_seed=101, speech_seed=11, sentences=TUNING_SENTENCES, voices=TUNING_VOICES)
HELD_OUT = CorpusSet(
    "held_out", clap_seed=202, speech_seed=22, sentences=HELD_OUT_SENTENCES, voices=HELD_OUT_VOICES
)


def espeak(text: str, voice: str, words_per_minute: int = 160, pitch: int = 50) -> Int16Array:
    """`text` spoken by espeak-ng (a required system package), 16 kHz mono. Deterministic."""
    binary = shutil.which("espeak-ng")
    if binary is None:
        raise RuntimeError("espeak-ng is required (apt-get install espeak-ng; scripts/bootstrap.sh does it)")
    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "speech.wav"
        subprocess.run(
            [binary, "-v", voice, "-s", str(words_per_minute), "-p", str(pitch), "-w", str(wav), text],
            check=True,
            capture_output=True,
        )
        pcm, rate, channels = read_wav(wav)
    return resample(to_mono(pcm, channels), rate, RATE)


def speech_stream(
    corpus: CorpusSet, seconds: float, noisy: bool, reverberant: bool = True
) -> tuple[Int16Array, list[str]]:
    """About `seconds` of the set's sentences in its voices (random speed and pitch), separated by
    0.2-1.5 s pauses, in a random room (or dry: a close microphone); `noisy` adds background noise
    at 20-35 dB below the speech. Returns the audio and a label per sentence ("voice: text")."""
    rng = np.random.default_rng(corpus.speech_seed + (1000 if noisy else 0) + (0 if reverberant else 2000))
    parts: list[FloatArray] = []
    labels: list[str] = []
    total = 0
    while total < seconds * RATE:
        text = corpus.sentences[int(rng.integers(len(corpus.sentences)))]
        voice = corpus.voices[int(rng.integers(len(corpus.voices)))]
        clip = espeak(text, voice, int(rng.integers(130, 200)), int(rng.integers(10, 80))).astype(np.float64)
        clip *= 10 ** (rng.uniform(-12.0, 0.0) / 20) / 32768.0
        pause = np.zeros(int(rng.uniform(0.2, 1.5) * RATE))
        parts += [clip, pause]
        labels.append(f"{voice}: {text}")
        total += len(clip) + len(pause)
    dry = np.concatenate(parts)
    room = RoomSpec(rt60_s=float(rng.uniform(0.2, 0.8)), direct_to_reverb_db=float(rng.uniform(0.0, 12.0)))
    wet = np.convolve(dry, room_impulse_response(rng, room))[: len(dry)] if reverberant else dry
    if noisy:
        speech_dbfs = 10 * np.log10(np.mean(wet[np.abs(wet) > 1e-4] ** 2) + 1e-12)
        kind = NOISE_KINDS[int(rng.integers(len(NOISE_KINDS)))]
        wet += background_noise(rng, kind, float(speech_dbfs - rng.uniform(20.0, 35.0)), len(wet))
    else:
        wet += background_noise(rng, "white", -80.0, len(wet))  # a real microphone is never silent
    return float_to_int16(wet), labels


def simple_scene(
    clap_times: Sequence[float],
    seconds: float = 3.0,
    seed: int = 0,
    timbre: Timbre = TIMBRES[1],
    peak: float = 0.3,
) -> ClapScene:
    """Claps of one timbre in a small, quiet room (RT60 0.3 s, close): the easy case."""
    rng = np.random.default_rng(seed)
    return place_claps(rng, clap_times, seconds, timbre, RoomSpec(0.3, 10.0), peak, "pink", -65.0)
