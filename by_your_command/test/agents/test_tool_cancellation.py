"""Tool calls the provider cancels (Gemini's toolCallCancellation): no result is sent for them, a
command not yet routed never reaches the robot, and the turn ends instead of timing out."""

from __future__ import annotations

import asyncio
import json

import pytest
from fake_port import running_agent, speak
from fake_provider import FakeFactory, Script
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig, AgentRole
from by_your_command.agents.events import (
    AssistantText,
    ResponseDone,
    ResponseStatus,
    ToolCall,
    ToolCallCancelled,
)
from by_your_command.agents.robot_tool import TOOL_NAME

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

TOOLS = AgentConfig(role=AgentRole.TOOLS, tool_verdict_timeout_s=3.0, reply_timeout_s=5.0)


def call(call_id: str, command: str, cancel_after_s: float | None, *cancel_ids: str) -> Script:
    steps: Script = [
        (0.1, ToolCall("r1", call_id, TOOL_NAME, json.dumps({"command": command}))),
        (0.0, ResponseDone("r1", ResponseStatus.COMPLETED)),
    ]
    if cancel_after_s is not None:
        steps.append((cancel_after_s, ToolCallCancelled(cancel_ids or (call_id,))))
    return steps


def said(response_id: str, text: str) -> Script:
    return [
        (0.1, AssistantText(response_id, "i", text, final=True)),
        (0.0, ResponseDone(response_id, ResponseStatus.COMPLETED)),
    ]


def tool_results(calls: list[tuple[str, object]]) -> list[object]:
    return [value for name, value in calls if name == "tool_result"]


def test_a_call_cancelled_with_it_is_never_routed_nor_answered() -> None:
    async def scenario() -> None:
        factory = FakeFactory(call("c1", "pan@left", 0.0), said("r2", "Yes?"))
        async with running_agent(TOOLS, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(10.0)  # past the verdict and reply deadlines: nothing may fire
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert agent.port.requests() == []
        assert tool_results(factory.last.calls) == []
        counters = agent.runtime.counters
        assert (counters.tool_calls_cancelled, counters.commands_withheld, counters.tool_timeouts) == (
            1,
            1,
            0,
        )
        assert [t.outcome for t in agent.port.turns()] == ["cancelled", "completed"]
        assert agent.port.of("text") == ["Yes?"]  # no failure report for the cancelled turn

    run_virtual(scenario())


def test_a_call_cancelled_after_routing_gets_no_result_even_when_the_verdict_comes() -> None:
    async def scenario() -> None:
        factory = FakeFactory(call("c1", "pan@left", 0.5))
        async with running_agent(TOOLS, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.3)
            assert agent.port.requests() == ["pan@left"]  # routed at once, not held back
            await asyncio.sleep(1.0)  # cancelled meanwhile
            agent.port.push(agent.port.verdict(0))
            await asyncio.sleep(5.0)
            await agent.stop()
        assert tool_results(factory.last.calls) == []
        counters = agent.runtime.counters
        assert (counters.tool_calls_cancelled, counters.commands_withheld, counters.tool_timeouts) == (
            1,
            0,
            0,
        )
        assert [t.outcome for t in agent.port.turns()] == ["cancelled"]

    run_virtual(scenario())


def test_cancelling_answered_or_unknown_calls_changes_nothing() -> None:
    async def scenario() -> None:
        late_cancel: Script = [(1.0, ToolCallCancelled(("c1", "never-issued")))]
        factory = FakeFactory(call("c1", "pan@left", None), said("r2", "Done.") + late_cancel)
        async with running_agent(TOOLS, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.5)
            agent.port.push(agent.port.verdict(0))
            await asyncio.sleep(3.0)
            await agent.stop()
        [(call_id, output)] = tool_results(factory.last.calls)  # type: ignore[misc]
        assert call_id == "c1" and json.loads(output)["accepted"] is True
        assert agent.runtime.counters.tool_calls_cancelled == 0
        assert [t.outcome for t in agent.port.turns()] == ["completed"]

    run_virtual(scenario())
