"""Sleep/wake/mute state and whole-phrase matching of wake and sleep phrases."""

from __future__ import annotations

import pytest

from by_your_command.vad.attention import Attention, AttentionState, PhraseCommand, PhraseMatcher
from by_your_command.vad.config import DEFAULT_SLEEP_PHRASES, DEFAULT_WAKE_PHRASES

matcher = PhraseMatcher(DEFAULT_WAKE_PHRASES, DEFAULT_SLEEP_PHRASES)


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("Wake up!", PhraseCommand.WAKE),
        ("hey robot, WAKE   up please", PhraseCommand.WAKE),
        ("wakeup", PhraseCommand.WAKE),
        ("Go to sleep.", PhraseCommand.SLEEP),
        ("sleep", PhraseCommand.SLEEP),
        ("I am awake", None),  # the seed's substring match woke on this
        ("that was a sleepy cat", None),
        ("the wakeful owl", None),
        ("what do you see?", None),
        ("", None),
    ],
)
def test_phrases_match_whole_words_only(text: str, expected: PhraseCommand | None) -> None:
    assert matcher.match(text) == expected


@pytest.mark.unit
def test_custom_multi_word_phrases() -> None:
    custom = PhraseMatcher(["hey barney"], ["good night robot"])
    assert custom.match("Hey,  Barney!") is PhraseCommand.WAKE
    assert custom.match("hey barneys") is None
    assert custom.match("good night robot") is PhraseCommand.SLEEP
    assert PhraseMatcher([], []).match("wake up") is None


@pytest.mark.unit
def test_mute_overrides_sleep_and_wake_and_is_restored() -> None:
    attention = Attention(awake=True)
    assert attention.state is AttentionState.AWAKE and attention.listening
    assert attention.set_muted(True)
    assert attention.state is AttentionState.MUTED and not attention.listening
    assert not attention.set_awake(False)  # still muted: no visible change
    assert attention.set_muted(False)
    assert attention.state is AttentionState.ASLEEP
    assert attention.set_awake(True)
    assert not attention.set_awake(True)
