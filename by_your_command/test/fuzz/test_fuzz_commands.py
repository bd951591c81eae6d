"""Hostile command text against the grammar and the command processor (pure level).

Any string gets verdicts (each accepted, or refused with a reason), never an exception; every
accepted command's normal form parses back to itself; and whatever the text (prompt injection,
look-alike letters, zero-width characters, JSON, megabytes), nothing outside the allow-list is
routed — `stop` excepted, which is always allowed.
"""

from __future__ import annotations

import pytest
from fuzzing import TALLY, fuzz_settings
from hypothesis import given
from hypothesis import strategies as st
from injection import INJECTED, INJECTIONS

from by_your_command.commands.grammar import CommandGrammar, Parsed
from by_your_command.commands.processor import CommandProcessor, Verdict
from by_your_command.commands.routing import route
from by_your_command.commands.safety import ALWAYS_ALLOWED, SafetyConfig, allow_list
from by_your_command.commands.vocabulary import load_vocabulary

pytestmark = [pytest.mark.unit, pytest.mark.timeout(600)]

VOCABULARY = load_vocabulary()
GRAMMAR = CommandGrammar(VOCABULARY)
NAMES = sorted(VOCABULARY.commands)
ANY_TEXT = st.text(max_size=300) | st.text(st.characters(codec="utf-8"), max_size=60)
VOCABULARY_SOUP = st.lists(
    st.sampled_from(
        [*NAMES, *VOCABULARY.bearings, "@", " ", ",", ";", ". ", "\n", "-", "+", "90", "1e3", "nan"]
    ),
    max_size=20,
).map("".join)
LONG_TEXT = st.tuples(
    st.sampled_from(["stop", "reach", "pan@left", "x", ", ", "stop, "]), st.integers(1, 3000)
).map(lambda part: part[0] * part[1])
MESSAGES = ANY_TEXT | VOCABULARY_SOUP | INJECTED | LONG_TEXT | st.sampled_from(INJECTIONS)


def check_normal_form(parsed: Parsed) -> None:
    """An accepted piece's normal form is plain ASCII and parses back to the same command."""
    command = parsed.command
    assert command is not None and not parsed.reason
    text = command.text
    assert text.isascii() and text == text.strip().lower(), text
    assert command.base in VOCABULARY.commands
    again = GRAMMAR.parse_message(text)
    assert [(p.command.text if p.command else None) for p in again] == [text], (text, again)


@fuzz_settings(short=300, long=20_000)
@given(MESSAGES)
def test_any_text_gets_verdicts_and_normal_forms_are_fixed_points(message: str) -> None:
    with TALLY.input("commands.grammar"):
        pieces = GRAMMAR.parse_message(message)
        assert pieces, "every message gets at least one verdict"
        for parsed in pieces:
            assert isinstance(parsed.raw, str) and len(parsed.raw) <= 4096 + 1
            if parsed.command is None:
                assert parsed.reason, parsed
            else:
                check_normal_form(parsed)


def check_routed_only_allowed(verdicts: list[Verdict], allowed: frozenset[str] | None) -> None:
    for verdict in verdicts:
        if not verdict.accepted:
            assert verdict.route is None and verdict.reason
            continue
        base = verdict.command.partition("@")[0]
        assert allowed is None or base in allowed or base == ALWAYS_ALLOWED, verdict
        assert verdict.route is not None
        [parsed] = GRAMMAR.parse_message(verdict.command)  # what goes out is itself a valid command
        assert parsed.command is not None and route(parsed.command) == verdict.route


ALLOW_LISTS = st.lists(st.sampled_from(NAMES), max_size=4)


@fuzz_settings(short=200, long=8_000)
@given(ALLOW_LISTS, st.lists(MESSAGES, min_size=1, max_size=4))
def test_injected_text_never_routes_a_command_outside_the_allow_list(
    allowed_names: list[str], messages: list[str]
) -> None:
    allowed = allow_list(allowed_names)
    processor = CommandProcessor(VOCABULARY, SafetyConfig(allowed, min_interval_s=0.0))
    with TALLY.input("commands.processor allow-list", count=len(messages)):
        for now, message in enumerate(messages):
            check_routed_only_allowed(processor.process(message, float(now)), allowed)


@pytest.mark.parametrize("message", INJECTIONS, ids=range(len(INJECTIONS)))
def test_known_injections_route_nothing_but_stop_and_lookup(message: str) -> None:
    processor = CommandProcessor(VOCABULARY, SafetyConfig(allow_list(["stop", "lookup"]), 0.0))
    verdicts = processor.process(message, 0.0)
    check_routed_only_allowed(verdicts, frozenset({"stop", "lookup"}))
    assert not any(v.accepted and v.command.startswith("reach") for v in verdicts)


def test_look_alike_letters_and_invisible_characters_are_refused_not_guessed() -> None:
    """The grammar does not fold look-alikes into commands: they are refused with a reason."""
    for text in ("r\u0435ach", "re\u200bach", "\uff52\uff45\uff41\uff43\uff48", "reach\u0301", "\u202ehcaer"):
        [parsed] = GRAMMAR.parse_message(text)
        assert parsed.command is None and "unknown command" in parsed.reason, (text, parsed)
