"""The Silero model and the whole detector pipeline on the committed speech corpus."""

from __future__ import annotations

import numpy as np
import pytest
from vad.corpus import Session, sessions

from by_your_command.audio.pcm import Int16Array, int16_to_float, resample
from by_your_command.vad.config import VadConfig
from by_your_command.vad.detector import Reblocker, VoiceDetector
from by_your_command.vad.model import WINDOW_SAMPLES, SileroModel, default_model_path
from by_your_command.vad.segmenter import UtteranceChunk, VoiceActivity

NS = 1_000_000_000
ONSET_TOLERANCE_S = 0.15
# The utterance ends after min_silence_duration_ms of silence; allow Silero's own lag on top.
OFFSET_TOLERANCE_S = (-0.1, 0.3)


@pytest.fixture(scope="module")
def model() -> SileroModel:
    return SileroModel()


def detect(
    pcm: Int16Array, config: VadConfig, model: SileroModel, block: int = 480
) -> tuple[list[tuple[float, float]], list[UtteranceChunk | VoiceActivity]]:
    """Feed `pcm` in blocks of `block` samples; return (start s, end s) per utterance and all events."""
    model.reset()
    detector = VoiceDetector(config, model)
    events: list[UtteranceChunk | VoiceActivity] = []
    for offset in range(0, len(pcm), block):
        events += detector.process(pcm[offset : offset + block], 16000, 1, offset * NS // 16000)
    spans: dict[int, int] = {}
    for event in events:
        if isinstance(event, UtteranceChunk):
            spans[event.utterance_id] = spans.get(event.utterance_id, 0) + len(event.samples)
    return [(uid / NS, uid / NS + n / 16000) for uid, n in spans.items()], events


@pytest.mark.unit
def test_model_is_found_in_the_wheel_without_importing_torch() -> None:
    import sys

    path = default_model_path()
    assert path.name == "silero_vad.onnx" and path.is_file()
    assert "torch" not in sys.modules and "silero_vad.utils_vad" not in sys.modules


@pytest.mark.unit
def test_model_tells_speech_from_silence(model: SileroModel) -> None:
    model.reset()
    assert model.probability(np.zeros(WINDOW_SAMPLES, dtype=np.float32)) < 0.1
    speech = next(s for s in sessions() if s.name == "clean_en_us")
    pcm = int16_to_float(speech.audio())
    start = int(1.2 * 16000)
    probs = [model.probability(pcm[i : i + WINDOW_SAMPLES]) for i in range(start, start + 20 * 512, 512)]
    assert max(probs) > 0.9
    with pytest.raises(ValueError, match="512"):
        model.probability(np.zeros(100, dtype=np.float32))


@pytest.mark.unit
@pytest.mark.parametrize("block", [1, 100, 512, 1000, 4096])
def test_reblocker_cuts_any_block_size_into_evenly_stamped_frames(block: int) -> None:
    reblocker = Reblocker(512, 16000)
    pcm = np.arange(5000, dtype=np.int16)
    frames = []
    for offset in range(0, len(pcm), block):
        frames += reblocker.push(pcm[offset : offset + block], 7 + offset * NS // 16000)
    assert len(frames) == 5000 // 512
    assert np.array_equal(np.concatenate([f.samples for f in frames]), pcm[: len(frames) * 512])
    assert [f.time_ns for f in frames] == [7 + i * 512 * NS // 16000 for i in range(len(frames))]


@pytest.mark.unit
@pytest.mark.parametrize("session", sessions(), ids=lambda s: s.name)
def test_segments_match_the_corpus_timeline(session: Session, model: SileroModel) -> None:
    # 400 ms of silence keeps espeak's comma pauses (~290 ms) inside one utterance.
    config = VadConfig(pre_roll_frames=0, utterance_chunk_frames=10, min_silence_duration_ms=400)
    found, events = detect(session.audio(), config, model)
    hangover = config.min_silence_frames(512) * 512 / 16000
    assert len(found) == len(session.segments), f"found {found}, expected {session.segments}"
    for (start, end), truth in zip(found, session.segments, strict=True):
        assert abs(start - truth.start) <= ONSET_TOLERANCE_S, (start, truth)
        assert OFFSET_TOLERANCE_S[0] <= end - hangover - truth.end <= OFFSET_TOLERANCE_S[1], (end, truth)
    ends = [e for e in events if isinstance(e, UtteranceChunk) and e.is_utterance_end]
    assert len(ends) == len(found)


@pytest.mark.unit
def test_default_settings_cover_every_spoken_segment_with_pre_roll(model: SileroModel) -> None:
    session = next(s for s in sessions() if s.name == "clean_en_us")
    config = VadConfig()  # 250 ms silence may split at a comma: coverage, not one-to-one
    found, _ = detect(session.audio(), config, model, block=512)
    for truth in session.segments:
        assert any(start <= truth.start and end >= truth.start for start, end in found)
        assert any(start <= truth.end <= end for start, end in found)
    # pre-roll: each utterance starts before the speech it contains
    assert found[0][0] <= session.segments[0].start - 0.3


@pytest.mark.unit
def test_resampled_and_stereo_input_is_detected_too(model: SileroModel) -> None:
    session = next(s for s in sessions() if s.name == "clean_en_us")
    pcm = resample(session.audio()[: 16000 * 4], 16000, 48000)
    stereo = np.repeat(pcm, 2)
    model.reset()
    detector = VoiceDetector(VadConfig(), model)
    events = []
    for offset in range(0, len(stereo), 1920):
        events += detector.process(stereo[offset : offset + 1920], 48000, 2, offset * NS // 96000)
    assert VoiceActivity in {type(e) for e in events}
    assert detector.resampled_blocks > 0
    with pytest.raises(ValueError):
        detector.process(np.zeros(3, dtype=np.int16), 16000, 2, 0)


@pytest.mark.unit
def test_silence_and_noise_produce_no_utterance(model: SileroModel) -> None:
    rng = np.random.default_rng(3)
    noise = (rng.standard_normal(16000 * 3) * 1000).astype(np.int16)
    for pcm in (np.zeros(16000 * 3, dtype=np.int16), noise):
        found, events = detect(pcm, VadConfig(), model)
        assert found == [] and events == []


T0 = 1_700_000_000 * NS  # a realistic epoch stamp
FRAME_NS = 512 * NS // 16000


def feed(
    detector: VoiceDetector, pcm: Int16Array, start_ns: int, block: int = 480, rate: int = 16000
) -> list[UtteranceChunk | VoiceActivity]:
    """Feed `pcm` in blocks stamped from `start_ns` by sample count (a continuous stream)."""
    events: list[UtteranceChunk | VoiceActivity] = []
    for offset in range(0, len(pcm), block):
        events += detector.process(pcm[offset : offset + block], rate, 1, start_ns + offset * NS // rate)
    return events


def chunks_by_utterance(events: list[UtteranceChunk | VoiceActivity]) -> dict[int, list[UtteranceChunk]]:
    grouped: dict[int, list[UtteranceChunk]] = {}
    for event in events:
        if isinstance(event, UtteranceChunk):
            grouped.setdefault(event.utterance_id, []).append(event)
    return grouped


def utterance_audio(chunks: list[UtteranceChunk]) -> Int16Array:
    return np.concatenate([c.samples for c in chunks])


def assert_cut_from(audio: Int16Array, start_ns: int, utterance_id: int, samples: Int16Array) -> None:
    """The utterance is exactly `audio` from the position its id names, nothing from elsewhere."""
    offset = (utterance_id - start_ns) * 16000 / NS
    assert offset >= 0, f"utterance starts {-offset / 16:.0f} ms before the stream it belongs to"
    assert offset == int(offset)
    assert np.array_equal(samples, audio[int(offset) : int(offset) + len(samples)])


def speech() -> Int16Array:
    return next(s for s in sessions() if s.name == "clean_en_us").audio()


@pytest.mark.unit
@pytest.mark.parametrize(
    ("resume_ns", "reason"),
    [(T0 + 6 * NS, "gap"), (T0 - 10 * NS, "jump back")],
    ids=["later", "earlier"],
)
def test_pre_roll_never_crosses_a_gap_in_the_stamps(model: SileroModel, resume_ns: int, reason: str) -> None:
    """Blocks dropped (echo gate while the robot spoke) or time jumping back: the next utterance
    starts after the gap with a fresh id, and holds no audio from before it."""
    pcm = speech()
    config = VadConfig(min_silence_duration_ms=400)  # pre-roll 480 ms
    model.reset()
    detector = VoiceDetector(config, model)
    before = pcm[: 4 * 16000]  # sentence 1 (1.0-3.0 s) and its trailing silence
    after = pcm[int(4.3 * 16000) : int(7.5 * 16000)]  # sentence 2 starts 0.21 s in: less than pre-roll
    events = feed(detector, before, T0)
    assert len(chunks_by_utterance(events)) == 1 and not detector.in_utterance
    events = feed(detector, after, resume_ns)
    assert detector.discontinuities == 1 and detector.last_discontinuity is not None
    assert detector.last_discontinuity.reason == reason
    ((utterance_id, chunks),) = chunks_by_utterance(events).items()
    assert utterance_id >= resume_ns
    assert_cut_from(after, resume_ns, utterance_id, utterance_audio(chunks))
    assert [c.chunk_sequence for c in chunks] == list(range(len(chunks))) and chunks[-1].is_utterance_end


@pytest.mark.unit
def test_a_gap_mid_utterance_ends_it_and_starts_a_new_one(model: SileroModel) -> None:
    pcm = speech()
    model.reset()
    detector = VoiceDetector(VadConfig(min_silence_duration_ms=400), model)
    before = pcm[: 2 * 16000]  # cut in the middle of sentence 1
    after = pcm[int(4.6 * 16000) : int(7.5 * 16000)]  # resumes in the middle of sentence 2
    events = feed(detector, before, T0)
    assert detector.in_utterance
    resume_ns = T0 + 3 * NS
    events += feed(detector, after, resume_ns)
    assert [e.active for e in events if isinstance(e, VoiceActivity)] == [True, False, True, False]
    first, second = chunks_by_utterance(events).items()
    assert first[0] < T0 + 2 * NS and first[1][-1].is_utterance_end
    # the first utterance ends at the gap: nothing after it joins
    assert_cut_from(before, T0, first[0], utterance_audio(first[1]))
    assert second[0] >= resume_ns
    assert_cut_from(after, resume_ns, second[0], utterance_audio(second[1]))


@pytest.mark.unit
def test_stamp_jitter_within_tolerance_is_no_gap(model: SileroModel) -> None:
    """Each block is compared with the previous one's end: jitter of +-40 ms stays under 100 ms."""
    pcm = speech()
    model.reset()
    detector = VoiceDetector(VadConfig(min_silence_duration_ms=400, gap_tolerance_ms=100), model)
    jitter = np.random.default_rng(5).integers(-40_000_000, 40_000_000, len(pcm) // 480 + 1)
    events = []
    for index, offset in enumerate(range(0, len(pcm), 480)):
        stamp = T0 + offset * NS // 16000 + int(jitter[index])
        events += detector.process(pcm[offset : offset + 480], 16000, 1, stamp)
    assert detector.discontinuities == 0
    assert len(chunks_by_utterance(events)) == len(
        next(s for s in sessions() if s.name == "clean_en_us").segments
    )


@pytest.mark.unit
def test_unstamped_blocks_continue_the_stream_by_sample_count(model: SileroModel) -> None:
    """Without a stamp the arrival time is all there is; its jitter must not look like gaps."""
    pcm = speech()[: 4 * 16000]
    model.reset()
    detector = VoiceDetector(VadConfig(min_silence_duration_ms=400), model)
    arrival_jitter = np.random.default_rng(7).integers(0, 400_000_000, len(pcm) // 480 + 1)
    arrival_jitter[0] = 0
    events = []
    for index, offset in enumerate(range(0, len(pcm), 480)):
        arrival = T0 + offset * NS // 16000 + int(arrival_jitter[index])
        events += detector.process(pcm[offset : offset + 480], 16000, 1, arrival, stamped=False)
    assert detector.discontinuities == 0
    ((utterance_id, chunks),) = chunks_by_utterance(events).items()
    assert_cut_from(pcm, T0, utterance_id, utterance_audio(chunks))
    # after stop() (audio timeout, sleep) the next unstamped block starts a new stream at its arrival
    detector.stop()
    events = feed(detector, pcm, T0 + 60 * NS)
    assert detector.discontinuities == 0
    ((utterance_id, chunks),) = chunks_by_utterance(events).items()
    assert_cut_from(pcm, T0 + 60 * NS, utterance_id, utterance_audio(chunks))


@pytest.mark.unit
def test_resampling_is_continuous_across_blocks(model: SileroModel) -> None:
    """48 kHz input in 10 ms blocks gives the same 16 kHz audio as resampling it in one go
    (per-block resampling left clicks of thousands of LSB at every block edge)."""
    pcm48 = resample(speech()[: 4 * 16000], 16000, 48000)
    whole = resample(pcm48, 48000, 16000)
    model.reset()
    detector = VoiceDetector(VadConfig(utterance_chunk_frames=0, min_silence_duration_ms=400), model)
    events = feed(detector, pcm48, T0, block=480, rate=48000)
    ((utterance_id, chunks),) = chunks_by_utterance(events).items()
    audio = utterance_audio(chunks)
    offset = (utterance_id - T0) * 16000 / NS
    assert offset == int(offset), "frames keep the time of their first sample through the resampler"
    reference = whole[int(offset) : int(offset) + len(audio)]
    assert np.abs(audio.astype(np.int32) - reference).max() <= 2


@pytest.mark.unit
def test_a_rate_change_starts_a_new_stream(model: SileroModel) -> None:
    pcm = speech()[: 2 * 16000]  # ends mid-sentence
    model.reset()
    detector = VoiceDetector(VadConfig(), model)
    pcm48 = resample(pcm, 16000, 48000)
    events = feed(detector, pcm48, T0, block=960, rate=48000)
    assert detector.in_utterance
    events += detector.process(pcm[:480], 16000, 1, T0 + 2 * NS)
    assert detector.last_discontinuity is not None and detector.last_discontinuity.reason == "rate change"
    ends = [e for e in events if isinstance(e, UtteranceChunk) and e.is_utterance_end]
    assert len(ends) == 1 and not detector.in_utterance


@pytest.mark.unit
@pytest.mark.parametrize(
    ("rate", "channels", "samples", "message"),
    [
        (4294967291, 1, 512, "sample_rate"),
        (1000003, 1, 512, "sample_rate"),
        (44101, 1, 512, "cannot be resampled"),
        (0, 1, 512, "sample_rate"),
        (16000, 0, 512, "channels"),
        (16000, 65535, 65535, "channels"),
        (16000, 2, 3, "whole number"),
        (16000, 1, 16000 * 11, "longer than"),
    ],
)
def test_bad_blocks_are_refused_and_the_stream_goes_on(
    model: SileroModel, rate: int, channels: int, samples: int, message: str
) -> None:
    model.reset()
    detector = VoiceDetector(VadConfig(min_silence_duration_ms=400), model)
    with pytest.raises(ValueError, match=message):
        detector.process(np.zeros(samples, dtype=np.int16), rate, channels, T0)
    events = feed(detector, speech()[: 4 * 16000], T0)
    assert len(chunks_by_utterance(events)) == 1
