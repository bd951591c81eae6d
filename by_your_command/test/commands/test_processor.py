"""The safety layer and the whole pure processor: allow-list, rate limit, stop, routing."""

from __future__ import annotations

import pytest

from by_your_command.commands.processor import CommandProcessor, CommandProcessorConfig
from by_your_command.commands.routing import Destination
from by_your_command.commands.safety import SafetyConfig, allow_list
from by_your_command.commands.vocabulary import load_vocabulary

VOCABULARY = load_vocabulary()


def processor(allowed: list[str] | None = None, interval: float = 1.0) -> CommandProcessor:
    return CommandProcessor(VOCABULARY, SafetyConfig(allow_list(allowed or []), interval))


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
    verdicts = gate.process("lookup, reach, stop", now=0.0)
    assert [(v.command, v.accepted) for v in verdicts] == [("lookup", True), ("reach", False), ("stop", True)]
    assert "allow-list" in verdicts[1].reason and verdicts[1].route is None


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
def test_bad_configuration_fails_at_startup() -> None:
    with pytest.raises(ValueError, match="unknown commands: dance"):
        processor(allowed=["dance", "stop"])
    with pytest.raises(ValueError, match="min_interval_s"):
        CommandProcessorConfig(min_interval_s=-1)
    with pytest.raises(ValueError, match="arm_topic"):
        CommandProcessorConfig(arm_topic=" ")


@pytest.mark.unit
def test_config_builds_a_processor_from_the_installed_vocabulary() -> None:
    built = CommandProcessorConfig(allowed_commands=["lookup", " "]).build()
    assert [v.accepted for v in built.process("lookup, reach", now=0.0)] == [True, False]
