"""A synthetic room for echo tests: far-end 'speech' played by a speaker and heard back by the mic.

Shared by the tests and bench/bench_aec.py so both measure the same thing.
"""

from __future__ import annotations

import functools
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from scipy.signal import fftconvolve, lfilter

from by_your_command.audio.pcm import Int16Array, float_to_int16, read_wav, resample, rms_dbfs, to_mono

CORPUS = Path(__file__).resolve().parents[1] / "data" / "corpus"
SENTENCES = (
    "The robot turned its head and looked at the door. Could you bring me the red cup from the table, "
    "please? After lunch we will check the battery and then go for a walk in the garden."
)


ROBOT_REPLY = (
    "Sure. I can see a red cup on the table, next to a blue book and a small green plant. "
    "Would you like me to pick up the cup and bring it over to you, or should I wait here "
    "until you have decided what to do next? I could also tidy the shelf by the window."
)


def espeak(text: str, voice: str, rate: int, wpm: int = 160) -> Int16Array:
    """`text` spoken by espeak-ng (a required system package) with `voice`, at `rate`."""
    return _espeak(text, voice, rate, wpm).copy()


@functools.lru_cache(maxsize=8)
def _espeak(text: str, voice: str, rate: int, wpm: int) -> Int16Array:
    binary = shutil.which("espeak-ng")
    if binary is None:
        raise RuntimeError("espeak-ng is missing: run scripts/bootstrap.sh")
    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "speech.wav"
        subprocess.run(
            [binary, "-v", voice, "-s", str(wpm), "-w", str(wav), text], check=True, capture_output=True
        )
        pcm, source_rate, channels = read_wav(wav)
    return resample(to_mono(pcm, channels), source_rate, rate)


def at_level(pcm: Int16Array, dbfs: float) -> Int16Array:
    """`pcm` scaled so that its RMS is `dbfs` dB full scale."""
    gain = 10 ** ((dbfs - rms_dbfs(pcm)) / 20)
    return float_to_int16(pcm.astype(np.float64) / 32768.0 * gain)


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
        heard = fftconvolve(far, self.impulse_response(rate, seed))[: len(far)]  # long tails: FFT
        heard += 10 ** (self.noise_dbfs / 20) * rng.standard_normal(len(far))
        return float_to_int16(heard)


def energy_db(pcm: Int16Array) -> float:
    power = float(np.mean(np.square(pcm.astype(np.float64)))) + 1e-9
    return 10.0 * float(np.log10(power))


@dataclass(frozen=True)
class Conversation:
    """The robot replies (`played`, what the player emitted) while the user may talk over it;
    `mic` is what the microphone captured, `user_spans` where the user speaks (s)."""

    played: Int16Array
    mic: Int16Array
    user_spans: list[tuple[float, float]]
    rate: int
    near: Int16Array | None = None  # the user alone, as the mic heard them (same length as mic)


def trim_silence(pcm: Int16Array, rate: int) -> Int16Array:
    """`pcm` without its leading and trailing quiet (10 ms frames 40 dB below its loudest), so a
    span starts where the speech does."""
    frame = rate // 100
    count = len(pcm) // frame
    if count == 0:
        return pcm
    power = np.mean(np.square(pcm[: count * frame].astype(np.float64)).reshape(count, frame), axis=1)
    loud = np.flatnonzero(power > 1e-4 * np.max(power))
    return pcm[loud[0] * frame : (loud[-1] + 1) * frame]


def conversation(
    rate: int,
    room: Room,
    echo_dbfs: float = -20.0,
    user_dbfs: float = -26.0,
    user_at_s: tuple[float, ...] = (),
    lead_s: float = 0.5,
    user_voice: str | None = None,
    user_room: Room | None = None,
) -> Conversation:
    """The robot says ROBOT_REPLY (espeak-ng en-gb, ~12 s) after `lead_s` of quiet; the mic hears it
    through `room` at `echo_dbfs` (RMS while it speaks) plus the user (corpus sentences, en-us, or
    the same sentences spoken by espeak-ng `user_voice`; at `user_dbfs`, through `user_room` if
    given) starting at each of `user_at_s`. A robot close to its mic is louder there than a user a
    metre away: -20 dBFS echo against -26 dBFS user is typical. `near` is the user part alone."""
    from vad.corpus import sessions  # the committed speech corpus (test/data/corpus)

    reply = espeak(ROBOT_REPLY, "en-gb", rate)
    lead = np.zeros(int(lead_s * rate), dtype=np.int16)
    played = np.concatenate([lead, at_level(reply, -18.0), lead])
    echo = room.echo(played, rate).astype(np.float64)
    speaking = slice(len(lead), len(lead) + len(reply))
    if echo_dbfs > -100:
        echo *= 10 ** ((echo_dbfs - rms_dbfs(float_to_int16(echo[speaking] / 32768.0))) / 20)
    else:  # no echo at all: the robot's voice does not reach the mic (a baseline)
        echo[:] = 0.0
    session = next(s for s in sessions() if s.name == "clean_en_us")
    corpus = resample(session.audio(), 16000, rate)
    near = np.zeros_like(echo)
    spans = []
    for k, start_s in enumerate(user_at_s):
        segment = session.segments[k % len(session.segments)]
        if user_voice is None:
            words = corpus[int(segment.start * rate) : int(segment.end * rate)]
        else:
            words = espeak(segment.text, user_voice, rate)
        if user_room is not None:
            words = user_room.echo(words, rate, seed=k + 5)
        words = at_level(trim_silence(words, rate), user_dbfs).astype(np.float64)
        at = int(start_s * rate)
        words = words[: max(0, len(near) - at)]
        near[at : at + len(words)] += words
        spans.append((start_s, start_s + len(words) / rate))
    mic = echo + near
    return Conversation(
        played, float_to_int16(mic / 32768.0), spans, rate, near=float_to_int16(near / 32768.0)
    )
