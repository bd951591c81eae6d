"""Double-clap detection on generated claps (timbres, rooms, distances, noise) and on speech."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from vad.corpus import sessions
from wake.clap_corpus import (
    RATE,
    TIMBRES,
    ClapScene,
    RoomSpec,
    Timbre,
    double_clap_scenes,
    espeak,
    place_claps,
    simple_scene,
)

from by_your_command.audio.clap import Clap, ClapConfig, ClapDetector, DoubleClap
from by_your_command.audio.clap_onsets import StreamHistory
from by_your_command.audio.pcm import Int16Array, float_to_int16

TEST_SEED = 303  # neither the tuning seed nor the held-out one of clap_corpus
Event = Clap | DoubleClap


def detect(pcm: Int16Array, blocks: list[int] | None = None, config: ClapConfig | None = None) -> list[Event]:
    detector = ClapDetector(config or ClapConfig())
    events: list[Event] = []
    offset = 0
    for size in itertools.cycle(blocks or [512]):
        if offset >= len(pcm):
            break
        events += detector.process(pcm[offset : offset + size])
        offset += size
    return events


def claps(events: list[Event]) -> list[Clap]:
    return [e for e in events if isinstance(e, Clap)]


def doubles(events: list[Event]) -> list[DoubleClap]:
    return [e for e in events if isinstance(e, DoubleClap)]


def found(scene: ClapScene, events: list[Event]) -> bool:
    """Exactly one double clap, made of the two claps placed (onsets within 10 ms)."""
    pairs = doubles(events)
    return len(pairs) == 1 and all(
        abs(clap.onset - placed) <= RATE // 100
        for clap, placed in zip((pairs[0].first, pairs[0].second), scene.clap_samples, strict=True)
    )


@pytest.mark.unit
def test_double_claps_of_all_timbres_rooms_and_distances_are_found() -> None:
    """20 double claps: bright to deep, RT60 0.2-0.9 s, peak 0.02-0.6, four kinds of room noise."""
    scenes = double_clap_scenes(TEST_SEED, 20)
    missed = [scene.description for scene in scenes if not found(scene, detect(scene.pcm))]
    assert len(missed) <= 1, missed


@pytest.mark.unit
@pytest.mark.parametrize("timbre", TIMBRES, ids=lambda t: t.name)
def test_far_claps_in_a_reverberant_room_are_found(timbre: Timbre) -> None:
    """The review's misses: dark claps (zero-crossing rate 0.1-0.25) and a far one at peak 0.02."""
    rng = np.random.default_rng(7)
    far = RoomSpec(rt60_s=0.7, direct_to_reverb_db=-3.0)
    scene = place_claps(rng, [1.0, 1.45], 3.0, timbre, far, peak=0.02, noise_dbfs=-62.0)
    assert found(scene, detect(scene.pcm))


@pytest.mark.unit
@pytest.mark.parametrize("gap_s", [0.2, 0.4, 0.7, 0.95])
def test_a_double_clap_is_reported_once_with_its_gap(gap_s: float) -> None:
    scene = simple_scene([0.8, 0.8 + gap_s], seconds=3.5)  # reported up to 1.3 s after the second clap
    events = detect(scene.pcm)
    assert len(claps(events)) == 2
    (double,) = doubles(events)
    assert double.gap_ms == pytest.approx(gap_s * 1000, abs=10)


# Sentences that woke the old detector (a double clap in each, e.g. "I stopped to look up at the
# stars" in six voices), spoken close to the microphone with faint hiss.
FOOLED_THE_OLD_DETECTOR = [
    ("I can't sleep at night.", "en-us", 80),
    ("I stopped to look up at the stars.", "en-gb", 50),
    ("I stopped to look up at the stars.", "en-us+m3", 20),
    ("Take the cup to the kitchen and put it back.", "en-gb+f2", 20),
    ("Could you check the top shelf, please?", "en-gb-scotland+m1", 80),
    ("Kick it to the captain, quick!", "en-us+m3", 50),
    ("Tap twice to start, then stop.", "en-gb", 50),
    ("That's it, that's it exactly.", "en-gb-scotland+m1", 20),
]


@pytest.mark.unit
def test_sentences_that_woke_the_old_detector_do_not_wake() -> None:
    rng = np.random.default_rng(1)
    parts = []
    for text, voice, pitch in FOOLED_THE_OLD_DETECTOR:
        parts += [np.zeros(RATE // 2), espeak(text, voice, 175, pitch) / 32768.0]
    speech = np.concatenate([*parts, np.zeros(RATE)])
    pcm = float_to_int16(speech + 10 ** (-70 / 20) * rng.standard_normal(len(speech)))
    events = detect(pcm)
    assert doubles(events) == []
    assert len(claps(events)) <= 1  # plosives one by one are rejected too, not just their pairs


@pytest.mark.unit
@pytest.mark.parametrize("room_noise", [0.0, 0.002, 0.01])
def test_the_speech_corpus_does_not_wake(room_noise: float) -> None:
    rng = np.random.default_rng(7)
    for session in sessions():
        speech = session.audio().astype(np.float64)
        pcm = np.clip(speech + rng.standard_normal(len(speech)) * room_noise * 32767, -32768, 32767)
        events = detect(pcm.astype(np.int16))
        assert doubles(events) == [], session.name
        assert len(claps(events)) <= 1, session.name


@pytest.mark.unit
def test_a_double_clap_in_a_pause_between_sentences_is_found() -> None:
    speech = next(s for s in sessions() if s.name == "clean_en_us").audio()[: 7 * RATE].astype(np.int32)
    scene = simple_scene([3.8, 4.3], seconds=7.0)
    mixed = np.clip(speech + scene.pcm.astype(np.int32), -32768, 32767).astype(np.int16)
    assert found(scene, detect(mixed))


@pytest.mark.unit
def test_a_room_echo_is_not_a_second_clap() -> None:
    """A wall's echo (363 ms, 12 dB down) lies inside the gap range: one clap + echo must not wake."""

    def with_echo(scene: ClapScene, delay_s: float = 0.363, gain: float = 0.25) -> Int16Array:
        pcm = scene.pcm.astype(np.float64)
        delay = int(delay_s * RATE)
        pcm[delay:] += gain * pcm[:-delay]
        echoed: Int16Array = np.clip(pcm, -32768, 32767).astype(np.int16)
        return echoed

    assert doubles(detect(with_echo(simple_scene([1.0])))) == []
    two = simple_scene([0.6, 1.3], seconds=3.0)
    assert found(two, detect(with_echo(two)))


@pytest.mark.unit
def test_gaps_outside_the_range_and_unlike_claps_do_not_wake() -> None:
    assert doubles(detect(simple_scene([0.8, 0.9]).pcm)) == []  # 100 ms: too fast
    assert doubles(detect(simple_scene([0.8, 2.0]).pcm)) == []  # 1.2 s: two separate claps
    rng = np.random.default_rng(3)
    quiet_room = RoomSpec(0.3, 10.0)
    loud = place_claps(rng, [0.8], 3.0, TIMBRES[1], quiet_room, 0.5, "pink", -70.0)
    faint = place_claps(rng, [1.3], 3.0, TIMBRES[1], quiet_room, 0.02, "pink", -90.0)
    both = (loud.pcm.astype(np.int32) + faint.pcm).astype(np.int16)  # 28 dB apart: not a pair
    assert doubles(detect(both)) == []


@pytest.mark.unit
def test_clapping_in_a_rhythm_does_not_wake_but_a_double_clap_after_it_does() -> None:
    """Applause or clapping to music is a rhythm, not the gesture: no other clap may come within
    1.25 gaps before the first or after the second."""
    rhythm = simple_scene([0.5, 0.9, 1.3, 1.7, 2.1], seconds=3.5)
    assert doubles(detect(rhythm.pcm)) == []
    assert doubles(detect(simple_scene([0.5, 0.9, 1.3], seconds=2.5).pcm)) == []
    then = simple_scene([0.5, 0.9, 1.3, 3.0, 3.4], seconds=4.5)
    (double,) = doubles(detect(then.pcm))
    assert (double.first.onset, double.second.onset) == pytest.approx(then.clap_samples[3:], abs=RATE // 100)


def _signature(events: list[Event], offset: int) -> list[tuple[object, ...]]:
    return [
        ("clap", e.onset - offset, e.features)
        if isinstance(e, Clap)
        else ("double", e.first.onset - offset, e.second.onset - offset)
        for e in events
    ]


_SCENE = simple_scene([0.7, 1.15], seconds=2.2, seed=5, timbre=TIMBRES[2], peak=0.05)
_REFERENCE = _signature(detect(_SCENE.pcm), 0)


@pytest.mark.unit
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    blocks=st.lists(st.integers(min_value=1, max_value=5000), min_size=1, max_size=12).filter(
        lambda sizes: sum(sizes) >= 64
    ),
    offset=st.integers(min_value=0, max_value=20000),
)
def test_detections_do_not_depend_on_block_sizes_or_start_offset(blocks: list[int], offset: int) -> None:
    """The same audio, cut anyhow and starting later in the stream (after digital silence), gives
    the same claps with the same features, and the same double clap."""
    assert len(_REFERENCE) == 3  # two claps and their double clap
    pcm = np.concatenate([np.zeros(offset, dtype=np.int16), _SCENE.pcm])
    assert _signature(detect(pcm, blocks), offset) == _REFERENCE


@pytest.mark.unit
def test_reset_starts_a_new_stream() -> None:
    scene = simple_scene([0.7, 1.2], seconds=2.5)
    detector = ClapDetector(ClapConfig())
    detector.process(scene.pcm[: int(0.9 * RATE)])  # first clap only, then a gap in the audio
    detector.reset()
    assert doubles(detector.process(scene.pcm[int(0.9 * RATE) :])) == []
    assert detector.claps == 1  # the counters carry on; the second clap counted, never paired


@pytest.mark.unit
def test_rejections_are_counted_by_reason() -> None:
    speech = sessions()[0].audio()
    detector = ClapDetector(ClapConfig())
    detector.process(speech)
    assert detector.onsets > 0
    assert sum(detector.rejected.values()) + detector.claps + detector.echoes >= detector.onsets - 3
    assert set(detector.rejected) <= {
        "quiet",
        "near_noise_floor",
        "slow_rise",
        "sound_before",
        "no_decay",
        "voice_around",
    }


@pytest.mark.unit
def test_stream_history_refuses_what_it_does_not_hold() -> None:
    history = StreamHistory(keep=100)
    history.append(np.arange(100, dtype=np.int16))
    history.append(np.arange(100, 200, dtype=np.int16))
    history.append(np.arange(200, 250, dtype=np.int16))  # full: the oldest 100 go
    assert list(history.segment(150, 160)) == list(range(150, 160))
    with pytest.raises(ValueError):
        history.segment(90, 110)  # gone
    with pytest.raises(ValueError):
        history.segment(240, 260)  # not yet
    with pytest.raises(ValueError):
        history.append(np.zeros(101, dtype=np.int16))
    fresh = StreamHistory(keep=100)
    fresh.append(np.array([1, 2, 3], dtype=np.int16))
    assert list(fresh.segment(-3, 2)) == [0, 0, 0, 1, 2]  # before the stream began: silence


@pytest.mark.unit
def test_bad_configuration_is_refused() -> None:
    with pytest.raises(ValueError):
        ClapConfig(double_clap_min_gap_ms=500, double_clap_max_gap_ms=400)
    with pytest.raises(ValueError):
        ClapConfig(double_clap_min_gap_ms=20)
    with pytest.raises(ValueError):
        ClapConfig(sample_rate=4_294_967_291)
    with pytest.raises(ValueError):
        ClapConfig(voicing_threshold=1.5)


@pytest.mark.unit
def test_the_config_file_shows_the_defaults() -> None:
    import dataclasses
    from pathlib import Path

    import yaml

    path = Path(__file__).resolve().parents[2] / "config" / "vad.yaml"
    shown = yaml.safe_load(path.read_text())["/**/clap_detector_node"]["ros__parameters"]
    defaults = {f.name: f.default for f in dataclasses.fields(ClapConfig)}
    assert shown == defaults
