"""ModelToolCalls on its own (agents/model_tool_calls.py): what the model's tool calls send to the
robot and when, what answers them, and where their results go — without a runtime, a provider or an
event loop of its own. (The same behaviour through the whole runtime: test_tool_cancellation.py,
test_modes.py, test_robot_calls.py.)"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import pytest
from fake_port import FakePort, running_agent, speak
from fake_provider import FakeFactory
from test_robot_calls import CATALOG, catalog_input, said
from test_robot_runner import FakeSession
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig, AgentRole
from by_your_command.agents.events import ToolCall, ToolCallCancelled
from by_your_command.agents.inputs import CommandStatus, ToolCatalog
from by_your_command.agents.metrics import Counters
from by_your_command.agents.model_tool_calls import MAX_ROUTE_DEFERRALS, ModelToolCalls
from by_your_command.agents.provider import ToolResult
from by_your_command.agents.robot_calls import RobotCall, RobotCalls
from by_your_command.agents.session import SendToolResults
from by_your_command.agents.tool_calls import PendingVerdicts
from by_your_command.agents.turn import Turn
from by_your_command.tools.catalog import Catalog

pytestmark = pytest.mark.unit

TOOLS = AgentConfig(role=AgentRole.TOOLS, tool_verdict_timeout_s=3.0)
GO_TO = Catalog.from_json(json.dumps(CATALOG)).get("go_to")


@dataclass
class Host:
    """What the runtime hands ModelToolCalls, recorded."""

    config: AgentConfig = TOOLS
    port: FakePort = field(default_factory=FakePort)
    counters: Counters = field(default_factory=Counters)
    robot_calls: RobotCalls = field(default_factory=RobotCalls)
    t: float = 100.0
    turn: Turn | None = field(default_factory=lambda: Turn(1, "voice", 100.0, 0))
    session: FakeSession | None = field(default_factory=lambda: FakeSession(1))
    sends: list[tuple[str, Callable[[], Awaitable[None]]]] = field(default_factory=list)
    started: list[tuple[int, str, str]] = field(default_factory=list)  # (serial, tool, arguments)
    stops: list[str] = field(default_factory=list)
    result_turns: list[tuple[int, tuple[ToolResult, ...]]] = field(default_factory=list)
    answered: int = 0

    def tool_calls(self) -> ModelToolCalls:
        return ModelToolCalls(
            self.config,
            self.counters,
            PendingVerdicts(),
            self.robot_calls,
            self.port,
            run="run",
            publish=lambda what, send: self.sends.append((what, send)),
            now=lambda: self.t,
            turn=lambda: self.turn,
            session=lambda: self.session,  # type: ignore[arg-type,return-value]
            start_robot=lambda serial, tool, call: self.started.append((serial, tool.name, call.arguments)),
            stop_robot=self.stops.append,
            result_turn=lambda serial, results: self.result_turns.append((serial, results)),
            answered=self._answered,
        )

    def _answered(self) -> None:
        self.answered += 1

    def flush(self) -> None:
        """Run what was published, in order (the outbox's job in the runtime)."""
        sends, self.sends = self.sends, []
        asyncio.run(_in_order([send for _, send in sends]))

    def results(self) -> list[list[tuple[str, dict[str, Any]]]]:
        """The results sent to the session, one list per request for a reply."""
        assert self.session is not None
        return [
            [(result.call_id, json.loads(result.output)) for result in message.results]
            for message in self.session.sent
            if isinstance(message, SendToolResults)
        ]


async def _in_order(sends: list[Callable[[], Awaitable[None]]]) -> None:
    for send in sends:
        await send()


def command_call(command: str, call_id: str = "c1", response_id: str = "r1") -> ToolCall:
    return ToolCall(response_id, call_id, "robot_command", json.dumps({"command": command}))


def verdict(request_id: str, accepted: bool = True) -> CommandStatus:
    return CommandStatus("pan@left", "pan@left", accepted, "arm_preset", "", request_id)


def test_a_command_is_routed_once_the_provider_events_queued_behind_its_call_are_handled() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    calls.route(provider_backlog=2)  # a cancellation may be among them
    calls.route(provider_backlog=1)
    assert host.sends == []
    calls.route(provider_backlog=0)
    host.flush()
    assert host.port.of("request") == [("agent-run-1", "pan@left")]
    calls.route(provider_backlog=0)
    host.flush()
    assert host.port.of("request") == [("agent-run-1", "pan@left")]  # once


def test_a_command_is_never_held_behind_more_than_the_deferral_limit() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    for _ in range(MAX_ROUTE_DEFERRALS):
        calls.route(provider_backlog=5)
    assert host.sends == []
    calls.route(provider_backlog=5)  # the provider keeps talking: routed all the same
    host.flush()
    assert host.port.requests() == ["pan@left"]


def test_a_cancelled_call_never_routed_is_withheld_and_its_turn_ends() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    assert host.turn is not None and host.turn.tool_calls_open == {"c1"}
    assert calls.on_cancelled(ToolCallCancelled(("c1",))) is True  # nothing more answers the turn
    calls.route(provider_backlog=0)
    calls.response_done("r1")
    host.flush()
    assert host.port.requests() == []  # the robot never saw it
    assert (host.counters.tool_calls_cancelled, host.counters.commands_withheld) == (1, 1)
    assert host.results() == [] and host.result_turns == []  # no result for a withdrawn call
    assert calls.waiting() == 0 and calls.next_deadline() is None


def test_the_other_results_of_a_response_go_without_the_cancelled_calls() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, ToolCall("r1", "c1", "fly", "{}"), duplex=False)  # refused at once
    calls.on_call(1, host.turn, command_call("pan@left", "c2"), duplex=False)
    calls.response_done("r1")
    assert host.results() == []  # c2 is still waiting for its verdict
    calls.on_cancelled(ToolCallCancelled(("c2",)))
    assert [[call_id for call_id, _ in results] for results in host.results()] == [["c1"]]


def test_a_cancelled_call_already_routed_is_counted_but_not_withheld() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    calls.route(provider_backlog=0)
    assert calls.on_cancelled(ToolCallCancelled(("c1",))) is True
    host.flush()
    assert host.port.requests() == ["pan@left"]
    assert (host.counters.tool_calls_cancelled, host.counters.commands_withheld) == (1, 0)


def test_a_cancellation_of_calls_never_ours_ends_no_turn() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    assert calls.on_cancelled(ToolCallCancelled(("other",))) is False
    assert calls.waiting() == 1 and host.counters.tool_calls_cancelled == 0
    quiet = Host()  # a turn that made no call (its reply is words only) is not ended either
    assert quiet.tool_calls().on_cancelled(ToolCallCancelled(("other",))) is False


def test_a_cancelled_robot_call_goes_on_and_only_leaves_the_turn() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.take_catalog(ToolCatalog(json.dumps(CATALOG)))
    calls.on_call(1, host.turn, ToolCall("r1", "c1", "go_to", "{}"), duplex=False)
    assert GO_TO is not None and host.started == [(1, "go_to", "{}")]
    running = RobotCall("c1", 1, GO_TO, "agent-run-1", "{}", 100.0, 160.0)
    host.robot_calls.start(running)
    assert calls.on_cancelled(ToolCallCancelled(("c1",))) is True
    assert running.orphaned  # its end becomes a note (agents/robot_runner.py)
    assert host.stops == [] and host.counters.tool_calls_cancelled == 0


def test_a_verdict_answers_its_call() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    calls.response_done("r1")
    calls.on_verdict(verdict("agent-run-1"))  # not routed yet: not ours to take
    assert host.results() == []
    calls.route(provider_backlog=0)
    calls.on_verdict(verdict("someone-else-1"))
    assert host.results() == []
    calls.on_verdict(verdict("agent-run-1"))
    assert host.results() == [[("c1", {"accepted": True, "command": "pan@left", "reason": "arm_preset"})]]
    assert host.answered == 1 and calls.waiting() == 0


def test_no_verdict_in_time_answers_no_answer_from_the_robot() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    calls.route(provider_backlog=0)
    calls.response_done("r1")
    assert calls.next_deadline() == pytest.approx(103.0)
    host.t = 102.9
    calls.verdicts_late()
    assert host.results() == [] and host.counters.tool_timeouts == 0
    host.t = 103.0
    calls.verdicts_late()
    assert host.results() == [
        [("c1", {"accepted": False, "command": "pan@left", "reason": "no answer from the robot"})]
    ]
    assert host.counters.tool_timeouts == 1 and host.answered == 1
    assert calls.next_deadline() is None


def test_the_results_of_one_response_are_sent_together_once_it_is_done() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, ToolCall("r1", "c1", "fly", "{}"), duplex=False)  # refused at once
    calls.on_call(1, host.turn, command_call("pan@left", "c2"), duplex=False)
    calls.route(provider_backlog=0)
    calls.on_verdict(verdict("agent-run-1"))
    assert host.results() == []  # the response may still make calls
    calls.response_done("r1")
    [[(first, refused), (second, accepted)]] = host.results()  # one request for a reply
    assert (first, refused["accepted"], refused["reason"]) == ("c1", False, "no tool named 'fly'")
    assert (second, accepted["accepted"]) == ("c2", True)
    assert host.counters.tool_calls == 2


def test_a_refused_call_is_answered_at_once_and_nothing_reaches_the_robot() -> None:
    host = Host(config=AgentConfig())  # a conversation agent has no tools
    calls = host.tool_calls()
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    assert host.turn is not None and host.turn.tool_calls_open == set()  # answered already
    assert host.answered == 1 and calls.waiting() == 0
    calls.route(provider_backlog=0)
    calls.response_done("r1")
    host.flush()
    assert host.port.requests() == []
    [[(_, result)]] = host.results()
    assert result == {"accepted": False, "command": "", "reason": "no tool named 'robot_command'"}


def test_results_whose_turn_is_over_make_a_turn_of_their_own() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    calls.response_done("r1")
    calls.route(provider_backlog=0)
    host.turn = Turn(2, "voice", 101.0, 0)  # the conversation went on
    calls.on_verdict(verdict("agent-run-1"))
    assert host.results() == []
    [(serial, results)] = host.result_turns
    assert serial == 1 and [result.call_id for result in results] == ["c1"]


def test_results_for_a_session_that_is_gone_are_not_sent_to_the_next() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, ToolCall("r1", "c1", "fly", "{}"), duplex=False)
    host.session = FakeSession(2)
    calls.response_done("r1")
    assert host.session.sent == [] and host.result_turns == []


def test_a_closed_session_forgets_its_results_and_drops_its_waiting_calls() -> None:
    host = Host()
    calls = host.tool_calls()
    calls.on_call(1, host.turn, ToolCall("r1", "c1", "fly", "{}"), duplex=False)
    calls.on_call(1, host.turn, command_call("pan@left", "c2", "r2"), duplex=False)
    calls.forget_results()
    calls.drop_waiting()
    assert calls.waiting() == 0 and calls.next_deadline() is None
    calls.response_done("r1")
    assert host.results() == [] and host.result_turns == []


def test_a_robot_tool_call_goes_to_the_runner_and_a_stop_command_stops_the_robot() -> None:
    host = Host()
    calls = host.tool_calls()
    assert calls.take_catalog(ToolCatalog(json.dumps(CATALOG)))
    calls.on_call(3, host.turn, ToolCall("r1", "c1", "go_to", '{"place": "kitchen"}'), duplex=False)
    assert host.started == [(3, "go_to", '{"place": "kitchen"}')]
    assert calls.waiting() == 0 and host.stops == []
    calls.on_call(3, host.turn, command_call("stop", "c2"), duplex=False)
    assert host.stops == ["stopped ('stop')"]
    calls.route(provider_backlog=0)
    host.flush()
    assert host.port.requests() == ["stop"]  # the command processor stops the motion too


@pytest.mark.parametrize("duplex", [True, False])
def test_a_duplex_delegation_saying_a_tools_phrase_starts_that_tool(duplex: bool) -> None:
    host = Host()
    calls = host.tool_calls()
    calls.take_catalog(ToolCatalog(json.dumps(CATALOG)))
    calls.on_call(1, host.turn, command_call("go to the kitchen"), duplex=duplex)
    calls.route(provider_backlog=0)
    host.flush()
    if duplex:
        assert host.started == [(1, "go_to", json.dumps({"place": "kitchen"}))]
        assert host.port.requests() == []
    else:
        assert host.started == [] and host.port.requests() == ["go to the kitchen"]


def test_a_changed_tool_list_recycles_the_session_and_is_offered_to_the_next() -> None:
    host = Host()
    calls = host.tool_calls()
    assert [spec.name for spec in calls.specs()] == ["robot_command"]
    assert calls.take_catalog(ToolCatalog(json.dumps(CATALOG))) is True
    assert [spec.name for spec in calls.specs()] == ["robot_command", "go_to", "battery"]
    assert calls.take_catalog(ToolCatalog(json.dumps(CATALOG))) is False  # the same tools
    assert calls.take_catalog(ToolCatalog("{not json")) is False
    assert host.counters.inputs_invalid == 1
    assert [spec.name for spec in calls.specs()] == ["robot_command", "go_to", "battery"]


def test_an_agent_without_tools_is_offered_none_whatever_the_robot_has() -> None:
    host = Host(config=AgentConfig())
    calls = host.tool_calls()
    assert calls.take_catalog(ToolCatalog(json.dumps(CATALOG))) is False
    assert calls.specs() == ()


def test_request_ids_name_the_agent_the_run_and_the_count() -> None:
    host = Host()
    calls = host.tool_calls()
    assert calls.new_request_id() == "agent-run-1"
    calls.on_call(1, host.turn, command_call("pan@left"), duplex=False)
    calls.route(provider_backlog=0)
    host.flush()
    assert host.port.of("request") == [("agent-run-2", "pan@left")]


def test_through_the_runtime_a_changed_tool_list_recycles_the_open_session() -> None:
    """The runtime's side of take_catalog: the open session goes, the next one is offered the tools."""

    async def scenario() -> None:
        factory = FakeFactory(said("r1", "Hello."), said("r2", "Hi again."))
        async with running_agent(TOOLS, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            agent.port.push(catalog_input())
            await asyncio.sleep(0.1)
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(1.0)
            assert agent.port.of("text") == ["Hello.", "Hi again."]
            first, second = factory.created
            assert first.setup is not None and second.setup is not None
            assert [tool.name for tool in first.setup.tools] == ["robot_command"]
            assert [tool.name for tool in second.setup.tools] == ["robot_command", "go_to", "battery"]
            assert agent.port.sessions()[0].close_reason == "the robot's tools changed"

    run_virtual(scenario())
