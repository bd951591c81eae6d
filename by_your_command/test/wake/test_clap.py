"""Clap detection on synthesized claps (with a room's reverb and echo) and on the speech corpus."""

from __future__ import annotations

import numpy as np
import pytest
from vad.corpus import sessions

from by_your_command.audio.clap import Clap, ClapConfig, ClapDetector, DoubleClap
from by_your_command.audio.pcm import Int16Array

RATE = 16000


def clap_sound(rng: np.random.Generator, amplitude: float = 0.5, decay_s: float = 0.006) -> np.ndarray:
    """A hand clap: a broadband burst rising in ~1 ms, decaying in a few ms, plus faint reverb."""
    t = np.arange(int(0.3 * RATE)) / RATE
    burst = rng.standard_normal(len(t)) * np.exp(-t / decay_s)
    burst[:16] *= np.linspace(0.0, 1.0, 16)
    burst /= np.abs(burst).max()
    reverb = rng.standard_normal(len(t)) * 0.02 * np.exp(-t / 0.08)
    return amplitude * (burst + reverb)


def scene(
    clap_times: list[float],
    seconds: float = 3.0,
    seed: int = 0,
    echo_delay_s: float | None = None,
    amplitudes: list[float] | None = None,
) -> Int16Array:
    rng = np.random.default_rng(seed)
    audio = rng.standard_normal(int(seconds * RATE)) * 0.002  # quiet room noise
    for index, start in enumerate(clap_times):
        sound = clap_sound(rng, (amplitudes or [0.5] * len(clap_times))[index])
        at = int(start * RATE)
        audio[at : at + len(sound)] += sound[: len(audio) - at]
        if echo_delay_s is not None:  # a wall's echo, 12 dB down
            echo_at = at + int(echo_delay_s * RATE)
            audio[echo_at : echo_at + len(sound)] += 0.25 * sound[: len(audio) - echo_at]
    return (np.clip(audio, -1, 1) * 32767).astype(np.int16)


def detect(pcm: Int16Array, block: int = 512, config: ClapConfig | None = None) -> list[Clap | DoubleClap]:
    detector = ClapDetector(config or ClapConfig())
    events: list[Clap | DoubleClap] = []
    for offset in range(0, len(pcm), block):
        events += detector.process(pcm[offset : offset + block])
    return events


def claps(events: list[Clap | DoubleClap]) -> list[Clap]:
    return [e for e in events if isinstance(e, Clap)]


def doubles(events: list[Clap | DoubleClap]) -> list[DoubleClap]:
    return [e for e in events if isinstance(e, DoubleClap)]


@pytest.mark.unit
@pytest.mark.parametrize("gap_s", [0.2, 0.4, 0.7, 1.1])
def test_a_double_clap_is_detected_once(gap_s: float) -> None:
    events = detect(scene([0.5, 0.5 + gap_s]))
    assert len(claps(events)) == 2
    (double,) = doubles(events)
    assert double.second.time_s - double.first.time_s == pytest.approx(gap_s, abs=0.01)


@pytest.mark.unit
@pytest.mark.parametrize("block", [1, 160, 512, 1600, 8000])
def test_one_clap_counts_once_whatever_the_block_size(block: int) -> None:
    events = detect(scene([1.0], seed=block), block=block)
    assert len(claps(events)) == 1 and doubles(events) == []
    assert claps(events)[0].time_s == pytest.approx(1.0, abs=0.005)


@pytest.mark.unit
def test_a_room_echo_inside_the_double_clap_window_is_not_a_second_clap() -> None:
    """The seed's room echo at ~363 ms fell inside 160-1200 ms and could wake the robot alone."""
    events = detect(scene([1.0], echo_delay_s=0.363))
    assert doubles(events) == []
    # ...while two real claps, each with its echo, still wake it
    events = detect(scene([0.5, 1.2], echo_delay_s=0.363))
    assert len(doubles(events)) == 1


@pytest.mark.unit
def test_gaps_outside_the_window_do_not_wake() -> None:
    assert doubles(detect(scene([0.5, 0.6]))) == []  # 100 ms: one clap's flutter, not two claps
    assert doubles(detect(scene([0.5, 2.0]))) == []  # 1.5 s: two separate claps
    assert doubles(detect(scene([0.5, 0.9], amplitudes=[0.5, 0.01]))) == []  # second one too quiet


@pytest.mark.unit
def test_three_claps_make_one_double_clap() -> None:
    events = detect(scene([0.3, 0.8, 1.3]))
    assert len(claps(events)) == 3 and len(doubles(events)) == 1


@pytest.mark.unit
@pytest.mark.parametrize("room_noise", [0.0, 0.002, 0.01])
def test_false_positive_rate_on_the_speech_corpus(
    room_noise: float, record_property: pytest.RecordProperty
) -> None:
    """Speech plosives are as sharp as claps; the context features keep them from waking the robot."""
    rng = np.random.default_rng(7)
    total_s = 0.0
    single = 0
    double = 0
    for session in sessions():
        speech = session.audio().astype(np.float64)
        pcm = np.clip(speech + rng.standard_normal(len(speech)) * room_noise * 32767, -32768, 32767)
        total_s += len(pcm) / RATE
        events = detect(pcm.astype(np.int16))
        single += len(claps(events))
        double += len(doubles(events))
    record_property("false_claps_per_minute", 60.0 * single / total_s)
    record_property("false_double_claps_per_minute", 60.0 * double / total_s)
    print(f"speech corpus {total_s:.1f} s + noise {room_noise}: {single} false claps, {double} false doubles")
    assert double == 0
    assert single <= 3


@pytest.mark.unit
def test_claps_over_speech_are_still_found() -> None:
    speech = next(s for s in sessions() if s.name == "clean_en_us").audio()[: 6 * RATE].astype(np.int32)
    claps_only = scene([3.7, 4.2], seconds=6.0).astype(np.int32)  # in the pause between sentences
    mixed = np.clip(speech + claps_only, -32768, 32767).astype(np.int16)
    found = doubles(detect(mixed))
    assert any(d.second.time_s == pytest.approx(4.2, abs=0.01) for d in found)


@pytest.mark.unit
def test_bad_configuration_is_refused() -> None:
    with pytest.raises(ValueError):
        ClapConfig(double_clap_min_gap_ms=500, double_clap_max_gap_ms=400)
    with pytest.raises(ValueError):
        ClapConfig(refractory_ms=200)
