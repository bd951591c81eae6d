"""The stop spotter's level segmenter: where an utterance starts and ends."""

from __future__ import annotations

import numpy as np
import pytest

from by_your_command.audio.pcm import Int16Array
from by_your_command.safety.config import StopConfig
from by_your_command.safety.segmenter import FRAME, NS_PER_S, RATE, Ended, LevelSegmenter, SegmentEvent

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
    return events


@pytest.mark.unit
def test_an_utterance_ends_with_the_word_not_with_the_echo_left_under_it() -> None:
    # A word at -20 dBFS, then 1 s of the robot's residual echo at -48 dBFS: above the room's floor
    # (alone it is speech), far under the word. The word's end is its utterance's end (the echo
    # may then be an utterance of its own).
    quiet = tone(0.5, -75)
    pcm = np.concatenate([quiet, tone(0.4, -20), tone(1.0, -48), quiet])
    ended = [e for e in segment(pcm) if isinstance(e, Ended)]
    assert ended[0].voice_start_ns == T0 + int(0.5 * NS_PER_S)
    assert ended[0].voice_end_ns == T0 + int(0.9 * NS_PER_S)
    # Judged on the floor alone, the echo carries the word on to its own end.
    assert [e for e in segment(pcm, None) if isinstance(e, Ended)][0].voice_end_ns == T0 + int(1.9 * NS_PER_S)


@pytest.mark.unit
def test_a_quieter_second_word_stays_in_the_utterance() -> None:
    # "stop ... it": the second word 10 dB under the first, after a short gap.
    quiet = tone(0.5, -75)
    pcm = np.concatenate([quiet, tone(0.3, -20), tone(0.08, -75), tone(0.2, -30), quiet])
    ended = [e for e in segment(pcm) if isinstance(e, Ended)]
    assert len(ended) == 1 and ended[0].voice_end_ns == T0 + int(1.08 * NS_PER_S)
