"""Speaker: espeak-ng replies as PCM, bounded and sanitised."""

from __future__ import annotations

import datetime
import stat
from pathlib import Path

import numpy as np
import pytest

from by_your_command.local_speech.replies import (
    NOT_CAUGHT,
    RepliesConfig,
    acknowledgement,
    answer,
    time_of_day,
)
from by_your_command.local_speech.speaker import Speaker, SpeakerConfig, SpeechError, sanitize


def _seconds(pcm: bytes, rate: int) -> float:
    return len(pcm) / 2 / rate


@pytest.mark.unit
def test_a_short_reply_becomes_audible_speech_of_plausible_length() -> None:
    pcm, rate = Speaker(SpeakerConfig(sample_rate=16000)).say("Looking up.")
    assert rate == 16000
    assert 0.4 < _seconds(pcm, rate) < 3.0
    samples = np.frombuffer(pcm, dtype=np.int16).astype(np.float64)
    assert np.sqrt(np.mean(samples**2)) > 300  # speech, not silence


@pytest.mark.unit
def test_longer_text_gives_longer_audio_at_the_configured_rate() -> None:
    speaker = Speaker(SpeakerConfig(sample_rate=24000))
    short, rate = speaker.say(NOT_CAUGHT)
    longer, _ = speaker.say(f"{NOT_CAUGHT} Please say it again, a little more slowly.")
    assert rate == 24000
    assert _seconds(longer, rate) > 1.5 * _seconds(short, rate)


@pytest.mark.unit
def test_text_that_looks_like_an_option_is_spoken_not_obeyed() -> None:
    pcm, rate = Speaker().say("--help -w /tmp/evil.wav")
    assert not Path("/tmp/evil.wav").exists()
    assert _seconds(pcm, rate) > 1.0  # espeak's help would have printed text, not audio


@pytest.mark.unit
def test_absurd_text_and_voices_are_refused() -> None:
    speaker = Speaker(SpeakerConfig(max_text_chars=100))
    with pytest.raises(ValueError, match="longer than 100"):
        speaker.say("la " * 10_000)
    with pytest.raises(ValueError, match="nothing to say"):
        speaker.say(" \x00\n\t[[]] ")
    assert sanitize("a\x1b[31m b\x00c [[h@l'oU]]", 100) == "a 31m b c h@l'oU"
    with pytest.raises(ValueError, match="voice"):
        SpeakerConfig(voice="--stdin")
    with pytest.raises(ValueError, match="words_per_minute"):
        SpeakerConfig(words_per_minute=10_000)


@pytest.mark.unit
def test_a_hung_or_missing_synthesizer_is_an_error_not_a_hang(tmp_path: Path) -> None:
    hung = tmp_path / "hung-espeak"
    hung.write_text("#!/bin/sh\nexec sleep 60\n")
    hung.chmod(hung.stat().st_mode | stat.S_IXUSR)
    with pytest.raises(SpeechError, match="longer than"):
        Speaker(SpeakerConfig(executable=str(hung), timeout_s=0.5)).say("hello")
    with pytest.raises(SpeechError, match="cannot run"):
        Speaker(SpeakerConfig(executable=str(tmp_path / "absent"))).say("hello")
    with pytest.raises(SpeechError, match="exited"):
        Speaker(SpeakerConfig(executable="false")).say("hello")


@pytest.mark.unit
def test_replies_acknowledge_commands_and_answer_questions() -> None:
    config = RepliesConfig(robot_name="Barney")
    assert acknowledgement("lookup", config) == "Looking up."
    assert acknowledgement("pan@full-left", config) == "Panning full left."
    assert acknowledgement("follow@me", config) == "Following you."
    assert acknowledgement("turn@-30", config) == "Turning -30 degrees."
    assert acknowledgement("dance", config) == "OK, dance."
    assert time_of_day(datetime.datetime(2026, 1, 2, 15, 5)) == "It is 3 05 PM."
    assert time_of_day(datetime.datetime(2026, 1, 2, 0, 0)) == "It is 12 o'clock AM."
    assert "Barney" in answer("identity", datetime.datetime.now(), config)
    assert answer("meaning of life", datetime.datetime.now(), config) == NOT_CAUGHT
