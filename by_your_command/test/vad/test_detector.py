"""The Silero model and the whole detector pipeline on the committed speech corpus."""

from __future__ import annotations

import numpy as np
import pytest
from vad.corpus import Session, sessions

from by_your_command.audio.pcm import Int16Array, int16_to_float
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
    from by_your_command.audio.pcm import resample

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
