"""RobotToolRunner on its own (agents/robot_runner.py): what it sends to the robot for a call, what
it answers the model with, and to whom — without a runtime, a provider or an event loop of its own.
(The same behaviour through the whole runtime: test_robot_calls.py.)"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import pytest
from fake_port import FakePort
from test_robot_calls import CATALOG

from by_your_command.agents.events import ToolCall
from by_your_command.agents.inputs import Attention, CallFeedback, CallReplied
from by_your_command.agents.metrics import ToolCallMetrics
from by_your_command.agents.robot_calls import RobotCalls
from by_your_command.agents.robot_runner import RobotToolRunner, SendFailed
from by_your_command.agents.session import SendToolProgress
from by_your_command.agents.tool_calls import PendingVerdicts
from by_your_command.tools.catalog import Catalog, RobotTool

pytestmark = pytest.mark.unit

TOOLS = Catalog.from_json(json.dumps(CATALOG))
GO_TO = TOOLS.get("go_to")
BATTERY = TOOLS.get("battery")
KITCHEN = json.dumps({"place": "kitchen"})
OBJECT = {"type": "object", "properties": {}, "additionalProperties": True}


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def wall(self) -> float:
        return self.t

    async def sleep(self, seconds: float) -> None:
        self.t += seconds


@dataclass
class FakeSession:
    serial: int
    sent: list[Any] = field(default_factory=list)

    def send(self, message: Any) -> None:
        self.sent.append(message)


@dataclass
class Host:
    """What the runtime hands the runner, recorded."""

    port: FakePort = field(default_factory=FakePort)
    clock: Clock = field(default_factory=Clock)
    session: FakeSession | None = field(default_factory=lambda: FakeSession(1))
    sends: list[tuple[str, Callable[[], Awaitable[None]]]] = field(default_factory=list)
    posted: list[SendFailed] = field(default_factory=list)
    delivered: list[tuple[str, dict[str, Any]]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    requests: int = 0

    def new_request_id(self) -> str:
        self.requests += 1
        return f"agent-run-{self.requests}"

    def flush(self) -> None:
        """Run what the runner published, in order (the outbox's job in the runtime)."""

        async def run_all() -> None:
            for _, send in self.sends:
                await send()

        asyncio.run(run_all())
        self.sends.clear()

    def states(self) -> list[str]:
        return [record.state for record in self.port.of("metrics") if isinstance(record, ToolCallMetrics)]


def runner_for(
    host: Host, calls: RobotCalls | None = None, verdicts: PendingVerdicts | None = None
) -> RobotToolRunner:
    return RobotToolRunner(
        "agent",
        calls if calls is not None else RobotCalls(),
        verdicts if verdicts is not None else PendingVerdicts(),
        10.0,
        host.port,  # type: ignore[arg-type]
        host.clock,
        new_request_id=host.new_request_id,
        publish=lambda what, send: host.sends.append((what, send)),
        post=host.posted.append,
        deliver=lambda call_id, output: host.delivered.append((call_id, json.loads(output))),
        tell_late=host.notes.append,
        session=lambda: host.session,  # type: ignore[arg-type,return-value]
    )


def start(runner: RobotToolRunner, tool: Any, arguments: str, call_id: str = "c1", session: int = 1) -> None:
    runner.start(session, tool, ToolCall("r1", call_id, tool.name, arguments), Attention.AWAKE, "")


def test_an_action_is_sent_as_a_goal_and_its_result_answers_the_call() -> None:
    host = Host()
    calls = RobotCalls()
    runner = runner_for(host, calls)
    start(runner, GO_TO, KITCHEN)
    host.flush()
    [(request_id, action, _, goal)] = host.port.of("goal")
    assert (request_id, action) == ("agent-run-1", "/navigate_to_pose")
    assert goal["pose"]["pose"]["position"] == {"x": 3.0, "y": 1.0}
    assert runner.started_action("r1") and not runner.started_action("r2")
    assert host.delivered == []  # it runs: nothing answered yet
    runner.on_reply(CallReplied(request_id, True, {"ok": 1}, status=4))
    host.flush()
    assert host.delivered == [
        ("c1", {"ok": True, "tool": "go_to", "status": "succeeded", "result": {"ok": 1}})
    ]
    assert host.states() == ["running", "succeeded"]
    assert len(calls) == 0


def test_a_refused_call_sends_nothing_to_the_robot_and_answers_why() -> None:
    host = Host()
    runner = runner_for(host)
    start(runner, GO_TO, json.dumps({"place": "the moon"}))
    host.flush()
    assert host.port.of("goal") == []
    [(call_id, result)] = host.delivered
    assert (call_id, result["status"]) == ("c1", "refused")
    assert result["error"].startswith("bad arguments")
    assert host.states() == ["refused"]
    assert host.requests == 0  # no request id spent on it


def test_progress_goes_to_the_session_that_made_the_call_only() -> None:
    host = Host()
    runner = runner_for(host)
    start(runner, GO_TO, KITCHEN)
    runner.on_reply(CallFeedback("agent-run-1", {"distance_remaining": 4.5}))
    assert host.session is not None
    [progress] = host.session.sent
    assert isinstance(progress, SendToolProgress) and progress.call_id == "c1"
    assert "4.5" in progress.text
    host.session = FakeSession(2)  # a new session: the call is not its own
    host.clock.t += 10.0
    runner.on_reply(CallFeedback("agent-run-1", {"distance_remaining": 1.0}))
    assert host.session.sent == []


def test_a_result_after_its_session_is_gone_becomes_a_note() -> None:
    host = Host()
    runner = runner_for(host)
    start(runner, GO_TO, KITCHEN)
    host.session = FakeSession(2)
    runner.on_reply(CallReplied("agent-run-1", True, {}, status=4))
    assert host.delivered == []
    [note] = host.notes
    assert "go_to" in note and "succeeded" in note


def test_a_stop_cancels_running_actions_once_and_a_service_is_left_to_end() -> None:
    host = Host()
    runner = runner_for(host)
    start(runner, GO_TO, KITCHEN, "c1")
    start(runner, BATTERY, "{}", "c2")
    runner.cancel_all("stopped")
    runner.cancel_all("stopped again")  # the first reason wins: one cancel
    host.flush()
    assert host.port.of("cancel") == [("agent-run-1", "/navigate_to_pose")]
    assert [service for _, service, _, _ in host.port.of("service")] == ["/battery_status"]


def test_deadlines_cancel_a_long_action_and_give_up_on_a_silent_service() -> None:
    host = Host()
    runner = runner_for(host)
    start(runner, GO_TO, KITCHEN, "c1")
    start(runner, BATTERY, "{}", "c2")
    host.flush()
    host.clock.t += 61.0  # past go_to's 60 s, and the service's 2 s and grace
    runner.due()
    host.flush()
    assert host.port.of("cancel") == [("agent-run-1", "/navigate_to_pose")]
    assert [(call_id, result["status"]) for call_id, result in host.delivered] == [("c2", "timeout")]


def test_a_request_the_bridge_could_not_take_is_posted_back_and_then_fails_the_call() -> None:
    host = Host()
    runner = runner_for(host)
    start(runner, BATTERY, "{}")

    host.port.unavailable = True  # the bridge is down: the send raises PortUnavailable
    what, send = host.sends[0]
    assert what == "robot tool"
    asyncio.run(send())  # the runner catches it: the scheduler is told, nothing raised
    assert host.posted == [SendFailed("agent-run-1", "bridge down")]
    runner.on_reply(host.posted[0])
    [(call_id, result)] = host.delivered
    assert (call_id, result["status"], result["ok"]) == ("c1", "unavailable", False)


def test_a_command_tool_waits_for_the_processors_verdict_and_sends_nothing_itself() -> None:
    host = Host()
    verdicts = PendingVerdicts()
    runner = runner_for(host, verdicts=verdicts)
    home = RobotTool("arm_home", "Arm home.", "command", "", "", OBJECT, command="arm@home")
    start(runner, home, "{}")
    host.flush()
    [pending] = verdicts.unrouted()
    assert (pending.call_id, pending.request_id, pending.command) == ("c1", "agent-run-1", "arm@home")
    assert pending.deadline == host.clock.now() + 10.0
    assert host.port.published == [] and host.delivered == []
