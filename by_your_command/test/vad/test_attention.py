"""Sleep/wake/mute state and matching of whole wake and sleep commands."""

from __future__ import annotations

import pytest

from by_your_command.vad.attention import Attention, AttentionState, PhraseCommand, PhraseMatcher
from by_your_command.vad.config import DEFAULT_SLEEP_PHRASES, DEFAULT_WAKE_PHRASES, VadConfig

WAKE, SLEEP = PhraseCommand.WAKE, PhraseCommand.SLEEP
matcher = PhraseMatcher(DEFAULT_WAKE_PHRASES, DEFAULT_SLEEP_PHRASES)
named = PhraseMatcher(DEFAULT_WAKE_PHRASES, DEFAULT_SLEEP_PHRASES, robot_name="Barney")

COMMANDS = [
    ("Wake up!", WAKE),
    ("wake up", WAKE),
    ("WAKE UP.", WAKE),
    ("Wake-up!", WAKE),
    ("wakeup", WAKE),
    ("Awaken.", WAKE),
    ("Wake!", WAKE),
    ("Please wake up.", WAKE),
    ("Hey, wake up now!", WAKE),
    ("ok wake up please", WAKE),
    ("  wake \t up  ", WAKE),
    ("Go to sleep.", SLEEP),
    ("go to sleep", SLEEP),
    ("Please go to sleep now.", SLEEP),
    ("Go to sleep, please!", SLEEP),
    ("Okay, go to sleep.", SLEEP),
    ("Sleep.", SLEEP),
    ("sleep now", SLEEP),
    ("Sleeptime!", SLEEP),
    ("Alright, sleep time.", None),  # not a configured phrase ("sleeptime" is)
]

SENTENCES = [
    # the review's examples: words of a phrase inside a sentence, negations, questions
    "I can't sleep",
    "I can't sleep at night",
    "How did you sleep?",
    "Don't go to sleep!",
    "don’t go to sleep",  # curly apostrophe
    "Do not go to sleep.",
    "don't wake the baby",
    "Don't wake up.",
    "Never wake up",
    "No, go to sleep",
    "Can you wake up?",
    "wake up?",
    "Go to sleep?",
    "Sleep?",
    "Should I go to sleep?",
    "It's time to go to sleep",
    "I need to wake up early tomorrow",
    "wake up and make some coffee",
    "The children went to sleep",
    "I am awake",  # the seed's substring match woke on this
    "that was a sleepy cat",
    "the wakeful owl",
    "she fell asleep",
    "what do you see?",
    "Please.",
    "hey",
    "",
    "   ",
    "?!",
    "wake up " * 40,  # too long to be a command
    "sleep sleep",
    "go to sleep wake up",
]


@pytest.mark.unit
@pytest.mark.parametrize(("text", "expected"), COMMANDS)
def test_a_whole_command_matches(text: str, expected: PhraseCommand | None) -> None:
    assert matcher.match(text) == expected


@pytest.mark.unit
@pytest.mark.parametrize("text", SENTENCES)
def test_sentences_negations_and_questions_never_match(text: str) -> None:
    assert matcher.match(text) is None
    assert named.match(text) is None


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("Barney, wake up!", WAKE),
        ("Hey Barney, wake up", WAKE),
        ("wake up, Barney", WAKE),
        ("Go to sleep, Barney.", SLEEP),
        ("Barney go to sleep please", SLEEP),
        ("Barney", None),
        ("Barney, don't go to sleep", None),
        ("Barney, how did you sleep?", None),
        ("Barney said wake up", None),
        ("Fred, wake up", None),  # another name: not addressed to this robot
    ],
)
def test_the_robot_name_may_frame_a_command(text: str, expected: PhraseCommand | None) -> None:
    assert named.match(text) == expected


@pytest.mark.unit
def test_custom_multi_word_phrases() -> None:
    custom = PhraseMatcher(["hey barney"], ["good night robot"])
    assert custom.match("Hey,  Barney!") is WAKE  # "hey" is filler only around the phrase
    assert custom.match("hey barneys") is None
    assert custom.match("Good night, robot.") is SLEEP
    assert custom.match("good night") is None
    assert PhraseMatcher([], []).match("wake up") is None


@pytest.mark.unit
@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"wake_phrases": ["wake up", "don't sleep"]}, "negation"),
        ({"sleep_phrases": ["not now"]}, "negation"),
        ({"sleep_phrases": ["..."]}, "no words"),
        ({"wake_phrases": ["sleep"]}, "both wake and sleep"),
    ],
)
def test_bad_phrases_are_refused_at_startup(kwargs: dict[str, list[str]], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        VadConfig(**kwargs)  # type: ignore[arg-type]


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
