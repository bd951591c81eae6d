"""Holding a command's words is not asking for it: asking.py."""

from __future__ import annotations

import pytest

from by_your_command.local_speech.asking import Verbs, inflections, not_asked_for

VERBS = Verbs(frozenset(("move", "turn", "look", "follow", "stop", "wake", "pan", "reach")))


def _not_asked(written: str, form: str, same_meaning: str = "", noisy: bool = False) -> bool:
    return not_asked_for(written.split(), form.split(), VERBS, set((same_meaning or form).split()), noisy)


@pytest.mark.unit
def test_a_verb_has_its_endings_and_its_irregular_past() -> None:
    assert {"turns", "turned", "turning"} <= inflections("turn")
    assert {"moved", "moving", "moves"} <= inflections("move")
    assert {"stopped", "stopping"} <= inflections("stop")
    assert {"panned", "reaches"} <= inflections("pan") | inflections("reach")
    assert {"woke", "slept", "froze"} <= inflections("wake") | inflections("sleep") | inflections("freeze")
    assert "lookked" not in inflections("look")  # no doubled consonant after two vowels
    assert "turn" not in inflections("turn")


@pytest.mark.unit
@pytest.mark.parametrize(
    ("written", "form"),
    [
        ("i turned left", "turn left"),
        ("and they moved forward", "move forward"),
        ("i'm moving forward", "move forward"),
        ("she follows the ball", "follow the ball"),
        ("i look up", "look up"),  # a subject right before a verb
        ("you turn left", "turn left"),
        ("i woke up", "look up"),  # another command's verb
        ("don't turn left", "turn left"),
        ("never follow me", "follow me"),
        ("if you turn left", "can you turn left"),  # the form's "you" does not make "if" a request
    ],
)
def test_a_subject_negation_condition_or_verb_ending_does_not_ask(written: str, form: str) -> None:
    assert _not_asked(written, form)


@pytest.mark.unit
@pytest.mark.parametrize(
    ("written", "form", "same_meaning"),
    [
        ("move forward", "move forward", ""),
        ("stop moving", "stop", "stop stop moving"),  # another form of the same meaning
        ("can you turn left", "can you turn left", ""),  # the form holds the "you"
        ("", "follow the ball", ""),  # nothing written is no evidence
        ("mum put left", "turn left", ""),  # misheard, but nothing says it is not asked for
        ("no turn right", "turn right", ""),  # a correction asks
        ("stop it", "stop", ""),  # "it" is an object as often as a subject
        ("i'm right", "pan right", ""),  # a subject, but no verb after it: "pan" misheard
        ("reached on the left", "reach to the left", ""),  # "reach to" sounds "reached"
        ("look up for it when pleased", "look up forward please", ""),  # only verbs' endings count
    ],
)
def test_a_command_as_written_asks_for_it(written: str, form: str, same_meaning: str) -> None:
    assert not _not_asked(written, form, same_meaning)


@pytest.mark.unit
def test_in_noise_we_and_you_count_only_before_a_verb_with_an_ending() -> None:
    """Noise before a command makes Moonshine start it "You look out right."."""
    assert not _not_asked("you look out right", "look out right", noisy=True)
    assert _not_asked("you look out right", "look out right", noisy=False)
    assert _not_asked("we moved left", "move left", noisy=True)
    assert _not_asked("i look up", "look up", noisy=True)
