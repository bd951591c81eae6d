"""End of turn after the VAD: Whisper features, the wait after a 'not finished' verdict, the model
loader. The decisions run on a scripted model; the real Smart Turn file is not needed."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from by_your_command.vad.config import VadConfig
from by_your_command.vad.end_of_turn import (
    WINDOW_SAMPLES,
    EndOfTurn,
    EndOfTurnConfig,
    ModelNotFoundError,
    SmartTurnModel,
    TurnEnd,
    fit_window,
    whisper_log_mel,
)
from by_your_command.vad.model import default_model_path
from by_your_command.vad.segmenter import FRAME_SAMPLES, Event, Frame, Segmenter

RATE = 16000
FRAME_NS = FRAME_SAMPLES * 1_000_000_000 // RATE
SPEECH, QUIET = 0.9, 0.05


class ScriptedModel:
    """Answers from a list of probabilities and keeps the audio it was shown."""

    def __init__(self, answers: list[float]) -> None:
        self.answers = list(answers)
        self.seen: list[npt.NDArray[np.float32]] = []

    def completion_probability(self, audio: npt.NDArray[np.float32]) -> float:
        self.seen.append(audio)
        return self.answers.pop(0)


def frames(probabilities: list[float], start: int = 0) -> list[tuple[Frame, float]]:
    """Frames whose samples hold 1000 + their index (speech) or 0 (quiet), 32 ms apart."""
    out = []
    for offset, p in enumerate(probabilities):
        index = start + offset
        value = 1000 + index if p >= 0.5 else 0
        out.append((Frame(np.full(FRAME_SAMPLES, value, np.int16), index * FRAME_NS), p))
    return out


def run(turns: EndOfTurn, probabilities: list[float], min_silence_ms: int = 250) -> list[tuple[int, TurnEnd]]:
    """Feed the frames through the real segmenter; (frame index, turn end) for each turn end."""
    segmenter = Segmenter(VadConfig(min_silence_duration_ms=min_silence_ms, pre_roll_frames=0))
    ends: list[tuple[int, TurnEnd]] = []
    for index, (frame, p) in enumerate(frames(probabilities)):
        events: list[Event] = segmenter.push(frame, p)
        ends += [(index, end) for end in turns.push(events)]
        timeout = turns.tick(frame.time_ns + FRAME_NS)
        if timeout is not None:
            ends.append((index, timeout))
    return ends


def test_a_finished_turn_ends_at_the_utterance_end() -> None:
    model = ScriptedModel([0.9])
    ends = run(EndOfTurn(EndOfTurnConfig(), model), [SPEECH] * 10 + [QUIET] * 100)
    assert len(ends) == 1
    index, end = ends[0]
    assert (end.reason, end.probability) == ("complete", 0.9)
    assert index == 10 + 8 - 1  # the 8th quiet frame closes the utterance (250 ms)
    assert end.time_ns == index * FRAME_NS
    (audio,) = model.seen
    assert len(audio) == 18 * FRAME_SAMPLES
    assert audio[0] == pytest.approx(1000 / 32768)


def test_speech_after_a_not_finished_verdict_joins_the_same_turn() -> None:
    model = ScriptedModel([0.1, 0.8])
    probabilities = [SPEECH] * 10 + [QUIET] * 25 + [SPEECH] * 10 + [QUIET] * 100
    ends = run(EndOfTurn(EndOfTurnConfig(), model), probabilities)
    assert [end.reason for _, end in ends] == ["complete"]
    assert ends[0][0] == 45 + 8 - 1
    first, both = model.seen
    # The second question sees the whole turn: both utterances, the pause between them as zeros.
    assert len(both) == (45 + 8) * FRAME_SAMPLES
    assert np.array_equal(both[: len(first)], first)
    pause = both[18 * FRAME_SAMPLES : 35 * FRAME_SAMPLES]
    assert not pause.any()
    assert both[35 * FRAME_SAMPLES] == pytest.approx((1000 + 35) / 32768)


def test_without_more_speech_the_turn_ends_when_the_wait_runs_out() -> None:
    config = EndOfTurnConfig(incomplete_wait_ms=1000)
    model = ScriptedModel([0.2])
    ends = run(EndOfTurn(config, model), [SPEECH] * 10 + [QUIET] * 100)
    assert len(ends) == 1
    index, end = ends[0]
    closed = 10 + 8 - 1
    assert (end.reason, end.probability) == ("timeout", 0.2)
    assert end.time_ns == closed * FRAME_NS + 1_000_000_000
    assert (index + 1) * FRAME_NS >= end.time_ns > index * FRAME_NS  # the first tick past it


def test_a_turn_is_not_ended_by_the_wait_while_someone_speaks() -> None:
    config = EndOfTurnConfig(incomplete_wait_ms=500)
    model = ScriptedModel([0.2, 0.2])
    # The second utterance starts 400 ms after the first closed and lasts past the deadline.
    probabilities = [SPEECH] * 10 + [QUIET] * 20 + [SPEECH] * 40 + [QUIET] * 200
    ends = run(EndOfTurn(config, model), probabilities)
    assert [end.reason for _, end in ends] == ["timeout"]
    assert ends[0][1].time_ns == (70 + 8 - 1) * FRAME_NS + 500_000_000
    assert len(model.seen) == 2


def test_a_broken_model_output_ends_the_turn_and_is_counted() -> None:
    turns = EndOfTurn(EndOfTurnConfig(), ScriptedModel([math.nan]))
    ends = run(turns, [SPEECH] * 10 + [QUIET] * 20)
    assert [end.reason for _, end in ends] == ["complete"]
    assert turns.bad_outputs == 1
    assert not turns.turn_open


def test_turn_audio_is_bounded_to_the_models_window() -> None:
    turns = EndOfTurn(EndOfTurnConfig(), ScriptedModel([0.1] * 10))
    run(turns, ([SPEECH] * 100 + [QUIET] * 20) * 5)  # 19 s, never finished
    held = sum(len(c.samples) for u in turns._utterances for c in u.chunks)
    assert held <= WINDOW_SAMPLES + 10 * FRAME_SAMPLES  # one chunk of slack
    assert len(turns.turn_audio()) == WINDOW_SAMPLES


def test_finish_ends_an_open_turn() -> None:
    turns = EndOfTurn(EndOfTurnConfig(), ScriptedModel([0.1]))
    run(turns, [SPEECH] * 10 + [QUIET] * 9)
    assert turns.turn_open
    end = turns.finish()
    assert end is not None and end.reason == "timeout"
    assert turns.finish() is None


@pytest.mark.parametrize(
    "kwargs",
    [
        {"threshold": 0.0},
        {"threshold": 1.0},
        {"threshold": math.nan},
        {"incomplete_wait_ms": -1},
        {"incomplete_wait_ms": 30_001},
        {"threads": 0},
    ],
)
def test_bad_config_is_refused(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        EndOfTurnConfig(**kwargs)  # type: ignore[arg-type]


def test_off_by_default() -> None:
    assert not EndOfTurnConfig().enabled
    assert EndOfTurnConfig(model_path="/x.onnx").enabled


def test_other_sample_rates_are_refused() -> None:
    with pytest.raises(ValueError):
        EndOfTurn(EndOfTurnConfig(), ScriptedModel([]), sample_rate=48000)


def test_the_window_keeps_the_last_8_s_and_pads_in_front() -> None:
    short = np.ones(100, np.float32)
    window = fit_window(short)
    assert window.shape == (WINDOW_SAMPLES,)
    assert not window[:-100].any() and window[-100:].all()
    long = np.arange(WINDOW_SAMPLES + 5, dtype=np.float32)
    assert fit_window(long)[0] == 5.0


def test_features_of_silence_are_the_floor() -> None:
    features = whisper_log_mel(np.zeros(WINDOW_SAMPLES, np.float32))
    assert features.shape == (80, 800) and features.dtype == np.float32
    assert np.allclose(features, -1.5)  # log10(1e-10) = -10, then (x + 4) / 4


def test_features_match_whispers_on_a_chirp() -> None:
    """Reference values from Whisper's feature extractor (as vendored by pipecat 1.14) for the
    same chirp: 200 Hz rising 120 Hz/s, from 2 s on."""
    t = np.arange(WINDOW_SAMPLES) / RATE
    chirp = (0.3 * np.sin(2 * np.pi * (200 * t + 60 * t**2)) * (t > 2)).astype(np.float32)
    features = whisper_log_mel(chirp)
    expected = {
        (20, 500): 1.6617318391799927,
        (27, 700): 1.6952002048492432,
        (10, 300): -0.07242350280284882,
        (5, 210): 0.2982718050479889,
        (50, 650): -0.2902873754501343,
    }
    for (mel, frame), value in expected.items():
        assert features[mel, frame] == pytest.approx(value, abs=1e-5)
    assert features.max() - features.min() <= 2.0  # floored 8 decades below the peak


def test_features_refuse_a_window_of_the_wrong_length() -> None:
    with pytest.raises(ValueError):
        whisper_log_mel(np.zeros(16000, np.float32))


def test_model_loader_refuses_a_missing_file_and_a_wrong_model() -> None:
    with pytest.raises(ModelNotFoundError):
        SmartTurnModel("/nonexistent/smart-turn.onnx")
    with pytest.raises(ValueError, match="not a Smart Turn"):
        SmartTurnModel(default_model_path())  # Silero: a real ONNX file with other inputs
