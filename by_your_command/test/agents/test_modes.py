"""Dual-agent mode (a command agent on the shared transcript) and tool mode (robot_command)."""

from __future__ import annotations

import asyncio
import json

import pytest
from fake_port import running_agent, speak
from fake_provider import FakeFactory, Script
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig, AgentRole, ContextSource
from by_your_command.agents.events import (
    AssistantText,
    ResponseDone,
    ResponseStatus,
    ToolCall,
    UserTranscript,
)
from by_your_command.agents.inputs import CommandStatus, SharedTurn
from by_your_command.agents.provider import Role
from by_your_command.agents.robot_tool import TOOL_NAME
from by_your_command.commands.processor import CommandProcessorConfig

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


def command_reply(response_id: str, text: str) -> Script:
    return [
        (0.1, UserTranscript("look to the left")),
        (0.1, AssistantText(response_id, "i1", text, final=True)),
        (0.0, ResponseDone(response_id, ResponseStatus.COMPLETED)),
    ]


def test_command_agent_publishes_commands_only_and_keeps_the_shared_transcript() -> None:
    async def scenario() -> None:
        config = AgentConfig(role=AgentRole.COMMAND, context_source=ContextSource.SHARED, pause_timeout_s=5.0)
        factory = FakeFactory(command_reply("r1", " pan@left "), command_reply("r2", "lookup"))
        async with running_agent(config, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            # the conversation agent (the authority) publishes the turns; this agent ingests them
            agent.port.push(SharedTurn(Role.USER, "look to the left"))
            agent.port.push(SharedTurn(Role.ASSISTANT, "Looking left."))
            await asyncio.sleep(10.0)  # paused: the session closes
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert agent.port.of("cmd") == ["pan@left", "lookup"]
        assert agent.port.voice() == [] and agent.port.of("transcript") == [] and agent.port.of("text") == []
        setup = factory.created[1].setup
        assert setup is not None and setup.audio_out is False
        assert [(h.role, h.text) for h in setup.history] == [
            (Role.USER, "look to the left"),
            (Role.ASSISTANT, "Looking left."),
        ]

    run_virtual(scenario())


def tool_call(response_id: str, call_id: str, command: str) -> Script:
    return [
        (0.1, ToolCall(response_id, call_id, TOOL_NAME, json.dumps({"command": command}))),
        (0.0, ResponseDone(response_id, ResponseStatus.COMPLETED)),
    ]


def said(response_id: str, text: str) -> Script:
    return [
        (0.1, AssistantText(response_id, "i", text, final=True)),
        (0.0, ResponseDone(response_id, ResponseStatus.COMPLETED)),
    ]


def test_tool_mode_returns_the_processor_verdict_or_no_answer_from_the_robot() -> None:
    """The verdicts come from the real CommandProcessor, matched by the request id it echoes."""

    async def scenario() -> None:
        config = AgentConfig(role=AgentRole.TOOLS, tool_verdict_timeout_s=3.0)
        factory = FakeFactory(
            tool_call("r1", "c1", "pan@left"),
            said("r2", "Done."),
            tool_call("r3", "c2", "dance@moon"),
            said("r4", "I can't do that."),
        )
        processor = CommandProcessorConfig(min_interval_s=0.0).build()
        async with running_agent(config, factory, processor) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.5)
            agent.port.processor = None  # the robot stops answering
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(5.0)
            await agent.stop()
        assert agent.port.requests() == ["pan@left", "dance@moon"]
        assert agent.port.of("cmd") == []  # tool calls never go out as anonymous response_cmd text
        provider = factory.last
        results = [json.loads(output) for name, (call, output) in _tool_results(provider.calls)]
        assert results == [
            {"accepted": True, "command": "pan@left", "reason": "arm command"},
            {"accepted": False, "command": "dance@moon", "reason": "no answer from the robot"},
        ]
        assert provider.setup is not None and [t.name for t in provider.setup.tools] == [TOOL_NAME]
        assert [t.outcome for t in agent.port.turns()] == ["completed", "completed"]
        assert agent.runtime.counters.tool_timeouts == 1

    run_virtual(scenario())


def test_a_call_with_several_commands_is_answered_with_every_verdict_and_only_its_own() -> None:
    async def scenario() -> None:
        config = AgentConfig(role=AgentRole.TOOLS, tool_verdict_timeout_s=3.0)
        factory = FakeFactory(tool_call("r1", "c1", "lookup, pan@left, dance@moon"), said("r2", "Done."))
        processor = CommandProcessorConfig(min_interval_s=0.0).build()
        async with running_agent(config, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.5)
            [(request_id, text)] = agent.port.of("request")
            # the same words from another source, and a verdict naming another request: not ours
            agent.port.push(CommandStatus("lookup", "lookup", False, "rate limited", "", "", 0, 1))
            agent.port.push(CommandStatus("lookup", "lookup", False, "other", "", "someone-else-1", 0, 1))
            verdicts = processor.process(text, 0.0)
            for index, v in reversed(list(enumerate(verdicts))):  # in any order
                agent.port.push(
                    CommandStatus(v.raw, v.command, v.accepted, v.reason, "", request_id, index, 3)
                )
            await asyncio.sleep(2.0)
            await agent.stop()
        [(_, (call, output))] = _tool_results(factory.last.calls)
        result = json.loads(output)
        assert call == "c1" and result["accepted"] is False
        assert [(c["command"], c["accepted"]) for c in result["commands"]] == [
            ("lookup", True),
            ("pan@left", True),
            ("dance@moon", False),
        ]
        assert "dance@moon" in result["reason"] and "unknown" in result["reason"]
        assert agent.runtime.counters.tool_timeouts == 0

    run_virtual(scenario())


def _tool_results(calls: list[tuple[str, object]]) -> list[tuple[str, tuple[str, str]]]:
    return [(name, value) for name, value in calls if name == "tool_result"]  # type: ignore[misc]


def test_bad_tool_arguments_are_answered_not_published() -> None:
    async def scenario() -> None:
        factory = FakeFactory(
            [
                (0.1, ToolCall("r1", "c1", TOOL_NAME, "{not json")),
                (0.0, ResponseDone("r1", ResponseStatus.COMPLETED)),
            ],
            said("r2", "Sorry."),
        )
        async with running_agent(AgentConfig(role=AgentRole.TOOLS), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert agent.port.of("cmd") == []
        [(_, (call, output))] = _tool_results(factory.last.calls)
        assert call == "c1" and json.loads(output)["accepted"] is False

    run_virtual(scenario())


def test_several_calls_in_one_response_are_answered_together_with_one_reply() -> None:
    async def scenario() -> None:
        config = AgentConfig(role=AgentRole.TOOLS, tool_verdict_timeout_s=3.0)
        calls: Script = [
            (0.1, ToolCall("r1", "c1", TOOL_NAME, json.dumps({"command": "pan@left"}))),
            (0.0, ToolCall("r1", "c2", TOOL_NAME, "{not json")),
            (0.0, ToolCall("r1", "c3", TOOL_NAME, json.dumps({"command": "lookup"}))),
            (0.0, ResponseDone("r1", ResponseStatus.COMPLETED)),
        ]
        factory = FakeFactory(calls, said("r2", "Done."), said("r3", "Done again."))
        processor = CommandProcessorConfig(min_interval_s=0.0).build()
        async with running_agent(config, factory, processor) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(3.0)
            await agent.stop()
        results = _tool_results(factory.last.calls)
        assert [call for _, (call, _) in results] == ["c1", "c2", "c3"]
        assert [json.loads(output)["accepted"] for _, (_, output) in results] == [True, False, True]
        names = factory.last.names()
        first_result = names.index("tool_result")
        assert names[first_result : first_result + 3] == ["tool_result"] * 3  # sent together
        assert agent.port.of("text") == ["Done."]  # one reply for the three calls
        assert [t.outcome for t in agent.port.turns()] == ["completed"]

    run_virtual(scenario())
