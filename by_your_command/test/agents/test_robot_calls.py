"""The robot's own tools in the agent runtime (docs/tools.md): an action runs while the conversation
goes on, its feedback reaches the model throttled, its result becomes the call's result whenever
it comes; a stop cancels it; bad arguments, the rules and the robot's failures come back as plain
tool errors, and nothing is sent to the robot for a refused call."""

from __future__ import annotations

import asyncio
import json
from typing import Any

import pytest
from fake_port import Agent, running_agent, speak
from fake_provider import FakeFactory, Script
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig, AgentRole
from by_your_command.agents.events import AssistantText, ResponseDone, ResponseStatus, ToolCall
from by_your_command.agents.inputs import (
    Attention,
    AttentionChanged,
    CallFeedback,
    CallReplied,
    PromptText,
    SafetyStop,
    ToolCatalog,
)
from by_your_command.agents.robot_calls import is_stop_request

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

TOOLS = AgentConfig(role=AgentRole.TOOLS, reply_timeout_s=5.0)
PLACES = {"kitchen": {"pose": {"pose": {"position": {"x": 3.0, "y": 1.0}}}}}
CATALOG: dict[str, Any] = {
    "version": 1,
    "tools": [
        {
            "name": "go_to",
            "description": "Drive to a named place.",
            "kind": "action",
            "ros_name": "/navigate_to_pose",
            "type": "by_your_command_msgs/action/NavigateToPose",
            "parameters": {
                "type": "object",
                "properties": {"place": {"type": "string", "enum": ["kitchen"]}},
                "required": ["place"],
                "additionalProperties": False,
            },
            "fixed": {"pose": {"header": {"frame_id": "map"}}},
            "arguments": [{"name": "place", "field": "", "choices": PLACES}],
            "command": "",
            "rules": {
                "while_asleep": False,
                "min_interval_s": 0.0,
                "max_duration_s": 60.0,
                "confirm": False,
                "timeout_s": 5.0,
            },
            "feedback": {"every_s": 3.0, "fields": ["distance_remaining"]},
            "spoken": ["go to the {place}"],
        },
        {
            "name": "battery",
            "description": "The battery level.",
            "kind": "service",
            "ros_name": "/battery_status",
            "type": "by_your_command_msgs/srv/Trigger",
            "parameters": {"type": "object", "properties": {}, "required": [], "additionalProperties": False},
            "fixed": {},
            "arguments": [],
            "command": "",
            "rules": {
                "while_asleep": True,
                "min_interval_s": 0.0,
                "max_duration_s": 60.0,
                "confirm": False,
                "timeout_s": 2.0,
            },
            "feedback": None,
            "spoken": ["battery status"],
        },
    ],
}


def catalog_input() -> ToolCatalog:
    return ToolCatalog(json.dumps(CATALOG))


def calls(*tool_calls: tuple[str, str, dict[str, Any]], response_id: str = "r1") -> Script:
    steps: Script = [
        (0.1, ToolCall(response_id, call_id, name, json.dumps(args))) for call_id, name, args in tool_calls
    ]
    steps.append((0.0, ResponseDone(response_id, ResponseStatus.COMPLETED)))
    return steps


def said(response_id: str, text: str) -> Script:
    return [
        (0.1, AssistantText(response_id, "i", text, final=True)),
        (0.0, ResponseDone(response_id, ResponseStatus.COMPLETED)),
    ]


def results(agent: Agent) -> list[dict[str, Any]]:
    return [
        json.loads(output)
        for provider in agent.factory.created
        for name, value in provider.calls
        if name == "tool_result"
        for _, output in [value]  # type: ignore[misc]
    ]


def progress(agent: Agent) -> list[str]:
    return [value[1] for p in agent.factory.created for name, value in p.calls if name == "progress"]  # type: ignore[index]


async def start_with_tools(agent: Agent) -> None:
    agent.port.push(catalog_input())
    await asyncio.sleep(0.1)


def goal_id(agent: Agent, index: int = 0) -> str:
    return str(agent.port.of("goal")[index][0])


def test_an_action_runs_while_the_conversation_goes_on_and_its_result_is_the_call_result() -> None:
    async def scenario() -> None:
        factory = FakeFactory(
            calls(("c1", "go_to", {"place": "kitchen"})),
            said("r2", "It is sunny."),
            said("r3", "I am in the kitchen."),
        )
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            [(request_id, action, action_type, goal)] = agent.port.of("goal")
            assert (action, action_type) == (
                "/navigate_to_pose",
                "by_your_command_msgs/action/NavigateToPose",
            )
            assert goal["pose"]["header"]["frame_id"] == "map"  # fixed in the declaration
            assert goal["pose"]["pose"]["position"]["x"] == 3.0  # the named place, not the model's numbers
            # the conversation goes on while the robot drives
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(1.0)
            assert agent.port.of("text")[-1] == "It is sunny."
            assert results(agent) == []
            agent.port.push(CallFeedback(request_id, {"distance_remaining": 2.5}))
            await asyncio.sleep(0.5)
            agent.port.push(CallReplied(request_id, True, {"error_code": 0}, status=4, is_action=True))
            await asyncio.sleep(1.0)
            assert [r["status"] for r in results(agent)] == ["succeeded"]
            assert results(agent)[0]["ok"] is True
            assert agent.port.of("text")[-1] == "I am in the kitchen."
            assert len(progress(agent)) == 1 and "2.5" in progress(agent)[0]
            assert len(factory.created) == 1  # the session stayed open for the result
        assert agent.runtime.robot_calls.counters.succeeded == 1

    run_virtual(scenario())


def test_feedback_reaches_the_model_at_most_once_per_period_whatever_the_robot_sends() -> None:
    async def scenario() -> None:
        factory = FakeFactory(calls(("c1", "go_to", {"place": "kitchen"})), said("r2", "Arrived."))
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            request_id = goal_id(agent)
            for step in range(1000):  # a flood over 10 s
                agent.port.push(CallFeedback(request_id, {"distance_remaining": 100.0 - step / 10}))
                await asyncio.sleep(0.01)
            await asyncio.sleep(3.5)
            told = progress(agent)
            assert len(told) == 5  # at once, then every 3 s: the latest summary each time
            assert "0.1" in told[-1]  # the newest value, not a stale one
            counters = agent.runtime.robot_calls.counters
            assert counters.feedback == 1000 and counters.feedback_sent == len(told)
            agent.port.push(CallReplied(request_id, True, {}, status=4, is_action=True))
            await asyncio.sleep(1.0)

    run_virtual(scenario())


def test_several_calls_of_one_response_are_answered_together_after_the_last() -> None:
    async def scenario() -> None:
        factory = FakeFactory(
            calls(("c1", "battery", {}), ("c2", "go_to", {"place": "kitchen"})),
            said("r2", "Battery is fine and I arrived."),
        )
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            [(service_id, service, _, request)] = agent.port.of("service")
            assert service == "/battery_status" and request == {}
            agent.port.push(CallReplied(service_id, True, {"success": True, "message": "87 %"}))
            await asyncio.sleep(1.0)
            assert results(agent) == []  # held for the action of the same response
            agent.port.push(CallReplied(goal_id(agent), True, {}, status=4, is_action=True))
            await asyncio.sleep(1.0)
            provider = factory.last
            outputs = [value for name, value in provider.calls if name == "tool_result"]
            assert [call_id for call_id, _ in outputs] == ["c1", "c2"]  # type: ignore[misc]
            assert agent.port.of("text") == ["Battery is fine and I arrived."]  # one reply for both

    run_virtual(scenario())


@pytest.mark.parametrize("how", ["typed", "safety", "model"])
def test_a_stop_cancels_every_running_action_and_the_model_hears_why(how: str) -> None:
    async def scenario() -> None:
        stop_reply = (
            calls(("c2", "robot_command", {"command": "stop"}), response_id="r3")
            if how == "model"
            else said("r3", "Okay.")  # the model does nothing: the agent's own check must cancel
        )
        factory = FakeFactory(
            calls(("c1", "go_to", {"place": "kitchen"})),
            stop_reply,
            said("r4", "Stopped."),
            said("r5", "Stopped."),
        )
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            request_id = goal_id(agent)
            if how == "model":  # the user's words go to the model, which stops the robot itself
                await speak(agent.port, 2, seconds=0.3)
            else:
                agent.port.push(PromptText("stop") if how == "typed" else SafetyStop("stop"))
            await asyncio.sleep(0.5)
            assert agent.port.of("cancel") == [(request_id, "/navigate_to_pose")]
            agent.port.push(CallReplied(request_id, True, {}, status=5, is_action=True))
            await asyncio.sleep(5.0)  # after the stop turn (no command processor: its verdict times out)
            result = next(r for r in results(agent) if r.get("tool") == "go_to")
            assert result["ok"] is False and result["status"] == "cancelled"
            assert "stop" in result["error"]

    run_virtual(scenario())


def test_an_interruption_or_chat_about_stops_does_not_cancel_an_action() -> None:
    assert is_stop_request("stop") and is_stop_request("Stop it, please!") and is_stop_request("halt now")
    assert not is_stop_request("the bus stop is near") and not is_stop_request("don't stop believing")

    async def scenario() -> None:
        factory = FakeFactory(calls(("c1", "go_to", {"place": "kitchen"})), said("r2", "It is."))
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            agent.port.push(PromptText("is the bus stop near?"))
            await asyncio.sleep(1.0)
            assert agent.port.of("cancel") == []

    run_virtual(scenario())


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        ({"place": "garage"}, "place"),
        ({"place": 3}, "place"),
        ({"place": "kitchen", "speed": 9}, "speed"),
        ({}, "place"),
    ],
)
def test_bad_arguments_are_a_tool_error_and_nothing_reaches_the_robot(
    args: dict[str, Any], fragment: str
) -> None:
    async def scenario() -> None:
        factory = FakeFactory(calls(("c1", "go_to", args)), said("r2", "I cannot go there."))
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            [result] = results(agent)
            assert result["ok"] is False and result["status"] == "refused"
            assert fragment in result["error"]
            assert agent.port.of("goal") == [] and agent.port.of("service") == []

    run_virtual(scenario())


def test_a_tool_not_allowed_while_asleep_is_refused_and_one_that_is_runs() -> None:
    async def scenario() -> None:
        factory = FakeFactory(
            calls(("c1", "go_to", {"place": "kitchen"}), ("c2", "battery", {})), said("r2", "Sleeping.")
        )
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)  # the turn was heard awake; it sleeps before the calls
            agent.port.push(AttentionChanged(Attention.ASLEEP))
            await asyncio.sleep(1.0)
            assert agent.port.of("goal") == []
            [(service_id, *_)] = agent.port.of("service")
            agent.port.push(CallReplied(service_id, True, {"success": True, "message": "87 %"}))
            await asyncio.sleep(1.0)
            go_to, battery = results(agent)
            assert go_to["status"] == "refused" and "asleep" in go_to["error"]
            assert battery["ok"] is True

    run_virtual(scenario())


@pytest.mark.parametrize(
    ("reply", "status", "fragment"),
    [
        (
            CallReplied("", False, None, "no action server /navigate_to_pose", "no_server", is_action=True),
            "unavailable",
            "no action server",
        ),
        (CallReplied("", False, None, "goal rejected", "rejected", is_action=True), "rejected", "rejected"),
        (CallReplied("", True, {"error_code": 104}, status=6, is_action=True), "failed", "104"),
    ],
)
def test_the_robots_failures_come_back_plainly(reply: CallReplied, status: str, fragment: str) -> None:
    async def scenario() -> None:
        factory = FakeFactory(calls(("c1", "go_to", {"place": "kitchen"})), said("r2", "I could not."))
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            agent.port.push(
                CallReplied(
                    goal_id(agent), reply.ok, reply.values, reply.error, reply.code, reply.status, True
                )
            )
            await asyncio.sleep(1.0)
            [result] = results(agent)
            assert result["ok"] is False and result["status"] == status and fragment in result["error"]

    run_virtual(scenario())


def test_a_service_that_never_answers_times_out_and_an_action_over_its_time_is_cancelled() -> None:
    async def scenario() -> None:
        factory = FakeFactory(
            calls(("c1", "battery", {})),
            said("r2", "No answer."),
            calls(("c2", "go_to", {"place": "kitchen"}), response_id="r3"),
            said("r4", "Took too long."),
        )
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(6.0)  # timeout_s 2 + the grace
            [timeout] = results(agent)
            assert timeout["status"] == "timeout"
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(61.0)  # max_duration_s 60
            assert agent.port.of("cancel") == [(goal_id(agent), "/navigate_to_pose")]
            agent.port.push(CallReplied(goal_id(agent), True, {}, status=5, is_action=True))
            await asyncio.sleep(1.0)
            assert "longer than 60 s" in results(agent)[-1]["error"]

    run_virtual(scenario())


def test_a_result_whose_session_is_gone_is_told_as_a_note_in_the_next() -> None:
    async def scenario() -> None:
        factory = FakeFactory(calls(("c1", "go_to", {"place": "kitchen"})), said("r2", "I arrived."))
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            factory.last.drop()  # the network drops the session while the robot drives
            await asyncio.sleep(1.0)
            agent.port.push(CallReplied(goal_id(agent), True, {}, status=4, is_action=True))
            await asyncio.sleep(2.0)
            notes = [value for name, value in factory.last.calls if name == "text"]
            assert len(factory.created) == 2 and len(notes) == 1
            assert "go_to" in str(notes[0]) and "succeeded" in str(notes[0])
            assert agent.port.of("text")[-1] == "I arrived."

    run_virtual(scenario())


def test_replies_for_calls_we_never_made_and_a_malformed_tool_list_are_counted_and_ignored() -> None:
    async def scenario() -> None:
        factory = FakeFactory()
        async with running_agent(TOOLS, factory) as agent:
            agent.port.push(ToolCatalog("{not json"))
            agent.port.push(CallReplied("forged-1", True, {}, status=4, is_action=True))
            agent.port.push(CallFeedback("forged-2", {"x": 1}))
            await asyncio.sleep(0.5)
            assert agent.runtime.counters.inputs_invalid == 1
            assert agent.runtime.robot_calls.counters.stray_replies == 2

    run_virtual(scenario())


def test_the_session_is_told_the_robots_tools_with_the_actions_marked_long_running() -> None:
    async def scenario() -> None:
        factory = FakeFactory(said("r1", "Hi."))
        async with running_agent(TOOLS, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            setup = factory.last.setup
            assert setup is not None
            tools = {tool.name: tool for tool in setup.tools}
            assert set(tools) == {"robot_command", "go_to", "battery"}
            assert tools["go_to"].long_running and not tools["battery"].long_running
            assert ("go to the kitchen", json.dumps({"place": "kitchen"})) in tools["go_to"].spoken

    run_virtual(scenario())


@pytest.mark.parametrize("keep", [True, False])
def test_the_session_waits_for_a_running_action_unless_told_not_to(keep: bool) -> None:
    async def scenario() -> None:
        config = AgentConfig(
            role=AgentRole.TOOLS, reply_timeout_s=5.0, pause_timeout_s=2.0, keep_session_while_acting=keep
        )
        factory = FakeFactory(calls(("c1", "go_to", {"place": "kitchen"})), said("r2", "I arrived."))
        async with running_agent(config, factory) as agent:
            await start_with_tools(agent)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(30.0)  # driving, far past the pause
            assert factory.last.closed is not keep
            agent.port.push(CallReplied(goal_id(agent), True, {}, status=4, is_action=True))
            await asyncio.sleep(2.0)
            assert agent.port.of("text")[-1] == "I arrived."
            if keep:  # the call's own result
                assert len(factory.created) == 1 and results(agent)[0]["status"] == "succeeded"
            else:  # a note to a new session
                assert len(factory.created) == 2 and results(agent) == []
                assert "succeeded" in next(v for n, v in factory.last.calls if n == "text")  # type: ignore[operator]

    run_virtual(scenario())
