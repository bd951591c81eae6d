"""The segmenter's invariants, checked on scripted and on random probability sequences."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from by_your_command.vad.config import VadConfig
from by_your_command.vad.segmenter import FRAME_SAMPLES, Frame, Segmenter, UtteranceChunk, VoiceActivity

FRAME_NS = FRAME_SAMPLES * 1_000_000_000 // 16000


def frame(index: int) -> Frame:
    """A frame whose every sample holds its index, so emitted audio can be traced back to frames."""
    return Frame(np.full(FRAME_SAMPLES, index, dtype=np.int16), 1_000 + index * FRAME_NS)


def run(
    config: VadConfig, probabilities: list[float], finish: bool = False
) -> list[UtteranceChunk | VoiceActivity]:
    segmenter = Segmenter(config)
    events: list[UtteranceChunk | VoiceActivity] = []
    for index, probability in enumerate(probabilities):
        events.extend(segmenter.push(frame(index), probability))
    if finish:
        events.extend(segmenter.finish())
    return events


def frame_ids(chunk: UtteranceChunk) -> list[int]:
    assert len(chunk.samples) % FRAME_SAMPLES == 0
    return [int(v) for v in chunk.samples[::FRAME_SAMPLES]]


def utterances(events: list[UtteranceChunk | VoiceActivity]) -> dict[int, list[UtteranceChunk]]:
    grouped: dict[int, list[UtteranceChunk]] = {}
    for event in events:
        if isinstance(event, UtteranceChunk):
            grouped.setdefault(event.utterance_id, []).append(event)
    return grouped


def check_invariants(events: list[UtteranceChunk | VoiceActivity], closed: bool) -> None:
    emitted: list[int] = []
    activity = [e.active for e in events if isinstance(e, VoiceActivity)]
    # voice_activity alternates True, False, True, ...
    assert activity == [i % 2 == 0 for i in range(len(activity))]
    groups = utterances(events)
    # every closed utterance has chunks; a still-open one may not have filled a chunk yet
    assert activity.count(False) <= len(groups) <= activity.count(True)
    for utterance_id, chunks in groups.items():
        assert [c.chunk_sequence for c in chunks] == list(range(len(chunks)))
        ends = [c.is_utterance_end for c in chunks]
        if closed or ends[-1]:
            assert ends == [False] * (len(chunks) - 1) + [True]
        else:
            assert not any(ends)
        ids = [i for c in chunks for i in frame_ids(c)]
        assert ids == list(range(ids[0], ids[0] + len(ids))), "frames must be contiguous"
        assert utterance_id == frame(ids[0]).time_ns, "utterance_id is the first emitted sample's time"
        emitted.extend(ids)
        # unvoiced_samples grows with the chunks, never beyond what was sent, and covers the pre-roll
        unvoiced = [c.unvoiced_samples for c in chunks]
        sent = np.cumsum([len(c.samples) for c in chunks]).tolist()
        assert unvoiced == sorted(unvoiced) and all(u <= s for u, s in zip(unvoiced, sent, strict=True))
    assert len(emitted) == len(set(emitted)), "no frame may be emitted twice"
    assert emitted == sorted(emitted)


@pytest.mark.unit
def test_onset_includes_pre_roll_once_and_end_is_marked() -> None:
    config = VadConfig(pre_roll_frames=3, utterance_chunk_frames=0, min_silence_duration_ms=64)
    events = run(config, [0.0] * 5 + [0.9] * 4 + [0.0] * 2 + [0.0] * 3)
    assert [e.active for e in events if isinstance(e, VoiceActivity)] == [True, False]
    (chunk,) = [e for e in events if isinstance(e, UtteranceChunk)]
    # pre-roll frames 2, 3, 4; speech 5..8; two silent frames (64 ms) end it
    assert frame_ids(chunk) == list(range(2, 11))
    assert chunk.is_utterance_end and chunk.chunk_sequence == 0
    assert chunk.utterance_id == frame(2).time_ns


@pytest.mark.unit
def test_unvoiced_samples_count_the_pre_roll_and_silence_runs_never_the_speech() -> None:
    """A barge-in judge counts speech as samples received minus these: a cough with a long pre-roll
    must not look like half a second of speech (issue 34)."""
    config = VadConfig(pre_roll_frames=15, utterance_chunk_frames=10, min_silence_duration_ms=250)
    # 20 quiet frames (15 become pre-roll), a 3-frame cough, silence until the end (8 frames)
    events = run(config, [0.0] * 20 + [0.9] * 3 + [0.0] * 12)
    chunks = [e for e in events if isinstance(e, UtteranceChunk)]
    received = sum(len(c.samples) for c in chunks)
    assert received == (15 + 3 + 8) * FRAME_SAMPLES
    assert chunks[-1].unvoiced_samples == (15 + 8) * FRAME_SAMPLES  # speech heard: the 3 frames
    assert chunks[0].unvoiced_samples == 10 * FRAME_SAMPLES  # the first chunk is all pre-roll
    # a pause shorter than the closing silence counts as unvoiced too, and speech after it does not
    events = run(
        VadConfig(pre_roll_frames=0, utterance_chunk_frames=0), [0.9] * 4 + [0.1] * 3 + [0.9] * 2 + [0.0] * 8
    )
    (chunk,) = [e for e in events if isinstance(e, UtteranceChunk)]
    assert len(chunk.samples) - chunk.unvoiced_samples == 6 * FRAME_SAMPLES


@pytest.mark.unit
def test_end_marker_is_sent_even_when_the_last_frame_fills_a_chunk() -> None:
    """The seed lost the end marker when the last frame completed a chunk (seed.md §11.1-1)."""
    config = VadConfig(pre_roll_frames=0, utterance_chunk_frames=4, min_silence_duration_ms=64)
    events = run(config, [0.9] * 6 + [0.0] * 2)  # 8 frames = exactly two chunks
    chunks = [e for e in events if isinstance(e, UtteranceChunk)]
    assert [len(frame_ids(c)) for c in chunks] == [4, 4]
    assert [c.is_utterance_end for c in chunks] == [False, True]
    # Closed from outside right after a full chunk went out: an empty end chunk carries the marker.
    segmenter = Segmenter(config)
    for index in range(4):
        segmenter.push(frame(index), 0.9)
    (end, _) = segmenter.finish()
    assert isinstance(end, UtteranceChunk) and end.is_utterance_end
    assert len(end.samples) == 0 and end.chunk_sequence == 1


@pytest.mark.unit
def test_hysteresis_keeps_the_utterance_through_middling_probabilities() -> None:
    config = VadConfig(threshold=0.5, pre_roll_frames=0, utterance_chunk_frames=0, min_silence_duration_ms=64)
    events = run(config, [0.9, 0.4, 0.4, 0.4, 0.9, 0.1, 0.4, 0.1])
    assert [e.active for e in events if isinstance(e, VoiceActivity)] == [True, False]
    (chunk,) = [e for e in events if isinstance(e, UtteranceChunk)]
    # 0.4 is above neg_threshold (0.35): no silence until 0.1; then 0.4 cannot stop the count
    assert frame_ids(chunk) == list(range(0, 7))


@pytest.mark.unit
def test_finish_closes_an_open_utterance_and_drops_pre_roll() -> None:
    config = VadConfig(pre_roll_frames=5, utterance_chunk_frames=2)
    segmenter = Segmenter(config)
    events: list[UtteranceChunk | VoiceActivity] = []
    for index in range(3):
        events += segmenter.push(frame(index), 0.9)
    events += segmenter.finish()
    chunks = [e for e in events if isinstance(e, UtteranceChunk)]
    # Every frame heard once, in order, and the last chunk carries the end marker.
    assert [i for c in chunks for i in frame_ids(c)] == [0, 1, 2]
    assert [c.is_utterance_end for c in chunks] == [False, True]
    assert events[-1] == VoiceActivity(False, frame(2).time_ns)
    assert segmenter.finish() == [] and not segmenter.in_utterance
    for index in range(3, 6):
        assert segmenter.push(frame(index), 0.0) == []  # pre-roll, until...
    assert segmenter.finish() == []  # ...sleeping forgets what was heard before
    events = segmenter.push(frame(6), 0.9) + segmenter.push(frame(7), 0.9)
    assert events[0] == VoiceActivity(True, frame(6).time_ns)
    [chunk] = [e for e in events if isinstance(e, UtteranceChunk)]
    assert frame_ids(chunk) == [6, 7] and chunk.utterance_id == frame(6).time_ns  # no pre-roll from before


@pytest.mark.unit
def test_max_buffer_frames_bounds_whole_utterance_mode() -> None:
    config = VadConfig(pre_roll_frames=0, utterance_chunk_frames=0, max_buffer_frames=5)
    events = run(config, [0.9] * 12, finish=True)
    chunks = [e for e in events if isinstance(e, UtteranceChunk)]
    assert [len(frame_ids(c)) for c in chunks] == [5, 5, 2]
    check_invariants(events, closed=True)


@pytest.mark.unit
@pytest.mark.parametrize(
    "kwargs",
    [
        {"threshold": 1.5},
        {"neg_threshold": 0.6},
        {"pre_roll_frames": -1},
        {"max_buffer_frames": 0},
        {"utterance_chunk_frames": -2},
        {"sample_rate": 8000},
        {"gap_tolerance_ms": 0},
        {"delivery_confirm_s": 0.0},
        {"delivery_confirm_s": float("nan")},
    ],
)
def test_bad_configuration_is_refused_with_a_message(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        VadConfig(**kwargs)  # type: ignore[arg-type]


probabilities = st.lists(
    st.one_of(st.floats(0.0, 1.0), st.sampled_from([0.0, 0.1, 0.4, 0.5, 0.9, 1.0])), max_size=300
)


@pytest.mark.unit
@settings(max_examples=300, deadline=None)
@given(
    probs=probabilities,
    pre_roll=st.integers(0, 20),
    chunk_frames=st.integers(0, 12),
    max_buffer=st.integers(1, 40),
    min_silence_ms=st.integers(0, 400),
    finish=st.booleans(),
)
def test_segmenter_invariants_hold_for_any_probabilities(
    probs: list[float], pre_roll: int, chunk_frames: int, max_buffer: int, min_silence_ms: int, finish: bool
) -> None:
    config = VadConfig(
        pre_roll_frames=pre_roll,
        utterance_chunk_frames=chunk_frames,
        max_buffer_frames=max_buffer,
        min_silence_duration_ms=min_silence_ms,
    )
    events = run(config, probs, finish=finish)
    check_invariants(events, closed=finish)
    limit = config.frames_per_chunk
    for chunks in utterances(events).values():
        assert all(len(frame_ids(c)) <= limit for c in chunks)
        assert all(len(frame_ids(c)) == limit for c in chunks if not c.is_utterance_end)
