"""The safety layer and the whole pure processor: allow-list, rate limit, stop, routing."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from by_your_command.commands.grammar import MessageLimits
from by_your_command.commands.processor import SUPERSEDED, CommandProcessor, CommandProcessorConfig
from by_your_command.commands.routing import Destination
from by_your_command.commands.safety import SafetyConfig, allow_list
from by_your_command.commands.vocabulary import load_vocabulary

VOCABULARY = load_vocabulary()


def processor(
    allowed: list[str] | None = None, interval: float = 1.0, limits: MessageLimits | None = None
) -> CommandProcessor:
    return CommandProcessor(VOCABULARY, SafetyConfig(allow_list(allowed or []), interval), limits)


@pytest.mark.unit
def test_routing_arm_behavior_and_wake() -> None:
    verdicts = processor().process("lookup\nfollow@person\nsleep\nwake\nright", now=0.0)
    assert [(v.command, v.route.destination if v.route else None, v.route.wake if v.route else None)
            for v in verdicts] == [
        ("lookup", Destination.ARM, None),
        ("follow@person", Destination.BEHAVIOR, None),
        ("sleep", Destination.BEHAVIOR, False),
        ("wake", Destination.BEHAVIOR, True),
        ("pan@right", Destination.ARM, None),
    ]  # fmt: skip
    assert all(v.accepted for v in verdicts)


@pytest.mark.unit
def test_allow_list_refuses_other_commands_but_never_stop() -> None:
    gate = processor(allowed=["lookup"])
    verdicts = gate.process("stop, lookup, reach", now=0.0)
    assert [(v.command, v.accepted) for v in verdicts] == [("stop", True), ("lookup", True), ("reach", False)]
    assert "allow-list" in verdicts[2].reason and verdicts[2].route is None


@pytest.mark.unit
def test_the_same_command_is_rate_limited_but_stop_never_is() -> None:
    gate = processor(interval=1.0)
    assert [v.accepted for v in gate.process("pan@left", now=10.0)] == [True]
    refused = gate.process("Pan @ LEFT", now=10.5)
    assert [v.accepted for v in refused] == [False]
    assert "rate limited" in refused[0].reason and refused[0].command == "pan@left"
    assert [v.accepted for v in gate.process("pan@right", now=10.5)] == [True]  # another command
    assert [v.accepted for v in gate.process("pan@left", now=11.0)] == [True]  # interval over
    assert [v.accepted for v in gate.process("stop\nstop\nstop", now=11.0)] == [True, True, True]


@pytest.mark.unit
def test_a_refused_command_does_not_restart_the_rate_window() -> None:
    gate = processor(interval=1.0)
    gate.process("lookup", now=0.0)
    gate.process("lookup", now=0.9)  # refused
    assert [v.accepted for v in gate.process("lookup", now=1.0)] == [True]


@pytest.mark.unit
def test_zero_interval_disables_rate_limiting() -> None:
    gate = processor(interval=0.0)
    assert [v.accepted for v in gate.process("lookup\nlookup", now=0.0)] == [True, True]


@pytest.mark.unit
def test_every_piece_of_a_message_gets_a_verdict() -> None:
    verdicts = processor().process("Hello there! lookup, bogus@1", now=0.0)
    assert [(v.raw, v.accepted) for v in verdicts] == [
        ("Hello there", False),
        ("lookup", True),
        ("bogus@1", False),
    ]
    assert all(v.reason for v in verdicts)


@pytest.mark.unit
def test_a_stop_goes_first_and_cancels_what_came_before_it_in_the_message() -> None:
    gate = processor()
    verdicts = gate.process("lookup, reach, hello, stop. pan@left", now=0.0)
    assert [(v.raw, v.command, v.accepted) for v in verdicts] == [
        ("stop", "stop", True),  # routed before anything else in the message
        ("lookup", "lookup", False),
        ("reach", "reach", False),
        ("hello", "", False),
        ("pan@left", "pan@left", True),  # after the stop: a new instruction, kept in order
    ]
    assert [v.reason for v in verdicts[1:3]] == [SUPERSEDED, SUPERSEDED] and "unknown" in verdicts[3].reason
    assert gate.stats.superseded == 2
    # a superseded command did not go out, so it does not start a rate-limit window
    assert [v.accepted for v in gate.process("lookup", now=0.1)] == [True]


@pytest.mark.unit
def test_a_stop_beyond_the_examined_pieces_still_goes_first() -> None:
    message = ", ".join(["lookup", *(f"chatter {index}" for index in range(30)), "stop"])
    verdicts = processor().process(message, now=0.0)
    assert (verdicts[0].command, verdicts[0].accepted) == ("stop", True)
    assert (verdicts[1].command, verdicts[1].reason) == ("lookup", SUPERSEDED)
    assert "11 more pieces after the first 20 were not examined" in verdicts[-1].reason
    assert not any(v.accepted for v in verdicts[1:])


@pytest.mark.unit
def test_an_oversize_message_gets_one_refused_verdict_and_is_counted() -> None:
    gate = processor()
    junk = "lookup, " * 131_072  # 1 MiB of plausible commands
    (verdict,) = gate.process(junk, now=0.0)
    assert not verdict.accepted and verdict.route is None
    assert f"message of {len(junk)} characters is longer than 4096: not examined" == verdict.reason
    assert len(verdict.raw) <= 201  # the excerpt, not the megabyte, goes back on command_status
    assert (gate.stats.messages, gate.stats.oversize_messages) == (1, 1)
    at_the_limit = ("lookup, chatter; " * 400)[:4096]
    assert len(gate.process(at_the_limit, now=5.0)) == 21 and gate.stats.oversize_messages == 1


@pytest.mark.unit
@pytest.mark.parametrize(
    ("inside", "stops"),
    [
        ("\nstop\n", True),
        (", STOP! ", True),
        ("\n- COMMAND: **stop**\n", True),
        (" please don't stop now ", False),  # a word in a sentence is not a command
        (" unstoppable, stopped ", False),
        ("\nstop@now\n", False),
    ],
)
def test_a_stop_in_an_oversize_message_still_counts_and_goes_first(inside: str, stops: bool) -> None:
    message = "x " * 300_000 + "lookup" + inside + "y " * 300_000
    verdicts = processor().process(message, now=0.0)
    assert "not examined" in verdicts[-1].reason and not verdicts[-1].accepted
    assert [(v.command, v.accepted) for v in verdicts[:-1]] == ([("stop", True)] if stops else [])


@pytest.mark.unit
@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.sampled_from(["stop", "lookup", "reach", "pan@left", "follow@cup", "hello", "sleep", "left"]),
        max_size=30,
    ),
    st.sampled_from([", ", "\n", "; ", ". "]),
)
def test_nothing_before_the_last_stop_goes_out_and_stops_lead(words: list[str], separator: str) -> None:
    verdicts = processor(interval=0.0).process(separator.join(words), now=0.0)
    stops = [v for v in verdicts if v.command == "stop"]
    assert verdicts[: len(stops)] == stops and all(v.accepted for v in stops)
    if "stop" in words:
        last_stop = len(words) - 1 - words[::-1].index("stop")
        accepted = [v.raw for v in verdicts[len(stops) :] if v.accepted]
        # only the first 20 pieces are examined; a stop beyond them still cancels all of those
        assert accepted == [word for word in words[last_stop + 1 : 20] if word != "hello"]


@pytest.mark.unit
def test_bad_configuration_fails_at_startup() -> None:
    with pytest.raises(ValueError, match="unknown commands: dance"):
        processor(allowed=["dance", "stop"])
    with pytest.raises(ValueError, match="min_interval_s"):
        CommandProcessorConfig(min_interval_s=-1)
    with pytest.raises(ValueError, match="arm_topic"):
        CommandProcessorConfig(arm_topic=" ")
    with pytest.raises(ValueError, match="max_message_chars"):
        CommandProcessorConfig(max_message_chars=0)


@pytest.mark.unit
def test_config_builds_a_processor_from_the_installed_vocabulary() -> None:
    built = CommandProcessorConfig(allowed_commands=["lookup", " "]).build()
    assert [v.accepted for v in built.process("lookup, reach", now=0.0)] == [True, False]
    small = CommandProcessorConfig(max_message_chars=12, max_commands_per_message=2).build()
    assert "longer than 12" in small.process("lookup, lookout", now=0.0)[-1].reason
    assert "1 more pieces after the first 2" in small.process("a, b, lookup", now=0.0)[-1].reason
