"""The stop spotter's level segmenter: where an utterance starts, pauses and ends."""

from __future__ import annotations

import numpy as np
import pytest

from by_your_command.audio.pcm import Int16Array
from by_your_command.safety.config import StopConfig
from by_your_command.safety.segmenter import (
    FRAME,
    NS_PER_S,
    RATE,
    Ended,
    LevelSegmenter,
    Paused,
    SegmentEvent,
)

T0 = 1_000 * NS_PER_S


def tone(seconds: float, dbfs: float) -> Int16Array:
    t = np.arange(int(seconds * RATE)) / RATE
    amplitude = 32768 * 10 ** (dbfs / 20) * np.sqrt(2)  # a sine's RMS is its peak / sqrt(2)
    return (amplitude * np.sin(2 * np.pi * 220 * t)).astype(np.int16)


def segment(pcm: Int16Array, end_drop_db: float | None = StopConfig.end_drop_db) -> list[SegmentEvent]:
    segmenter = LevelSegmenter(-50, 9, end_silence_ms=180, max_utterance_ms=1800, end_drop_db=end_drop_db)
    events: list[SegmentEvent] = []
    for k in range(0, len(pcm) - FRAME + 1, FRAME):
        events += segmenter.push(pcm[k : k + FRAME], T0 + k * NS_PER_S // RATE)
    return [e for e in events if isinstance(e, Paused | Ended)]


def at(seconds: float) -> int:
    return T0 + int(seconds * NS_PER_S)


@pytest.mark.unit
def test_a_word_over_the_echo_left_under_it_pauses_where_the_word_ends() -> None:
    # A word at -20 dBFS, then 1 s of the robot's residual echo at -48 dBFS: above the room's floor
    # (alone it is speech), far under the word. The utterance pauses at the word's end (the
    # spotter may decide there) and, judged on the floor, ends with the echo.
    quiet = tone(0.5, -75)
    pcm = np.concatenate([quiet, tone(0.4, -20), tone(1.0, -48), quiet])
    assert segment(pcm) == [Paused(at(0.5), at(0.9)), Ended(at(0.5), at(1.9))]
    assert segment(pcm, None) == [Ended(at(0.5), at(1.9))]  # no pauses where nothing is cancelled


@pytest.mark.unit
def test_a_quieter_second_word_is_no_pause_and_a_quiet_end_is_no_pause() -> None:
    # "stop ... it": the second word 10 dB under the first, after a short gap; then the room.
    quiet = tone(0.5, -75)
    pcm = np.concatenate([quiet, tone(0.3, -20), tone(0.08, -75), tone(0.2, -30), quiet])
    assert segment(pcm) == [Ended(at(0.5), at(1.08))]
