"""A tool call of the model, without the runtime (agents/tool_calls.py): what it is, whether a robot
tool's rules let it run now, the verdicts a `robot_command` call waits for (matched by request id,
only once routed), and results held per response until all are in. (Through the runtime:
test_tool_cancellation.py, test_robot_calls.py; the real graph: test_robot_tools_graph.py.)"""

from __future__ import annotations

import json

import pytest

from by_your_command.agents.events import ToolCall
from by_your_command.agents.inputs import Attention, CommandStatus
from by_your_command.agents.provider import ToolResult
from by_your_command.agents.robot_calls import MAX_ACTIVE_CALLS, RobotCall, RobotCalls
from by_your_command.agents.tool_calls import (
    PendingVerdicts,
    Refuse,
    ResponseResults,
    RouteCommand,
    RunRobotTool,
    decide,
    refusal,
)
from by_your_command.tools.catalog import Catalog, RobotTool
from by_your_command.tools.config import ToolRules

pytestmark = pytest.mark.unit

OBJECT = {"type": "object", "properties": {}, "additionalProperties": True}
DOCK = RobotTool(
    "dock", "Dock.", "action", "/dock", "nav/action/Dock", OBJECT, rules=ToolRules(min_interval_s=5.0)
)
ARM = RobotTool("arm_home", "Arm home.", "service", "/arm", "std_srvs/srv/Trigger", OBJECT)
OPEN = RobotTool(
    "open_door",
    "Open it.",
    "service",
    "/door",
    "std_srvs/srv/Trigger",
    OBJECT,
    rules=ToolRules(confirm=True, while_asleep=True),
)
CATALOG = Catalog((DOCK, ARM, OPEN))


def call(name: str, arguments: str = "{}") -> ToolCall:
    return ToolCall("r1", "c1", name, arguments)


def verdict(request_id: str, index: int, count: int, accepted: bool = True) -> CommandStatus:
    reason = "" if accepted else "unknown preset"
    return CommandStatus(
        "pan@left", "pan@left", accepted, reason, request_id=request_id, index=index, count=count
    )


def test_what_a_call_is() -> None:
    assert decide(call("dock"), tool_mode=True, catalog=CATALOG) == RunRobotTool(DOCK)
    assert decide(call("robot_command", '{"command": "pan@left"}'), True, CATALOG) == RouteCommand("pan@left")
    bad = decide(call("robot_command", '{"command": 7}'), True, CATALOG)
    assert isinstance(bad, Refuse) and json.loads(bad.output)["accepted"] is False
    unknown = decide(call("launch_rocket"), True, CATALOG)
    assert isinstance(unknown, Refuse) and "no tool named 'launch_rocket'" in unknown.output
    # an agent that is not in tool mode has no tools at all, not even the robot's
    assert isinstance(decide(call("dock"), tool_mode=False, catalog=CATALOG), Refuse)
    assert isinstance(decide(call("robot_command", '{"command": "stop"}'), False, CATALOG), Refuse)


def test_the_rules_of_a_robot_tool() -> None:
    calls = RobotCalls()
    awake = Attention.AWAKE
    assert refusal(DOCK, "{}", awake, calls, "", now=0.0) == ""
    assert "waits until it is woken" in refusal(DOCK, "{}", Attention.ASLEEP, calls, "", now=0.0)
    calls.start(RobotCall("c1", 1, DOCK, "q1", "{}", started_at=0.0, deadline=60.0))
    assert "may run again in 4.0 s" in refusal(DOCK, "{}", awake, calls, "", now=1.0)
    for n in range(MAX_ACTIVE_CALLS - 1):
        calls.start(RobotCall(f"c{n + 2}", 1, ARM, f"q{n + 2}", "{}", started_at=0.0, deadline=60.0))
    assert "already doing" in refusal(ARM, "{}", awake, calls, "", now=9.0)
    idle = RobotCalls()
    sure = '{"confirmed": true}'
    assert "spoken yes" in refusal(OPEN, sure, awake, idle, "open the door", now=0.0)  # no yes heard
    assert "spoken yes" in refusal(OPEN, "{}", awake, idle, "yes please", now=0.0)  # not confirmed
    assert refusal(OPEN, sure, Attention.ASLEEP, idle, "Yes, go ahead.", now=0.0) == ""  # while_asleep


def test_verdicts_are_matched_by_request_id_and_taken_only_once_routed() -> None:
    pending = PendingVerdicts()
    pending.add("c1", "q1", "pan@left, lookup", deadline=10.0)
    assert [c.request_id for c in pending.unrouted()] == ["q1"]
    assert pending.take(verdict("q1", 0, 2)) is None  # not routed yet: not ours to take
    pending.routed("q1")
    assert pending.take(verdict("other-agent", 0, 1)) is None
    assert pending.take(verdict("q1", 5, 2)) is None  # malformed index: the deadline answers
    assert pending.take(verdict("q1", 1, 2, accepted=False)) is None  # one of two
    taken = pending.take(verdict("q1", 0, 2))
    assert taken is not None
    done, verdicts = taken
    assert done.call_id == "c1" and [v.index for v in verdicts] == [0, 1] and len(pending) == 0
    pending.add("c2", "q2", "wave", deadline=5.0)
    pending.add("c3", "q3", "lookup", deadline=8.0)
    pending.routed("q3")
    assert pending.next_deadline() == 5.0
    cancelled = pending.cancel("c2")
    assert cancelled is not None and cancelled[1] is False  # withdrawn before the robot saw it
    assert [c.call_id for c in pending.expired(now=8.0)] == ["c3"] and len(pending) == 0


def test_results_go_together_once_the_response_is_done_and_every_call_answered() -> None:
    results = ResponseResults()
    results.expect(session=1, response_id="r1", call_id="a", turn=4)
    results.expect(session=1, response_id="r1", call_id="b", turn=4)
    results.answer("b", "B")
    results.response_done("r1")
    assert results.take_ready() == []  # "a" is still out
    results.answer("a", "A")
    assert results.take_ready() == [(1, 4, (ToolResult("a", "A"), ToolResult("b", "B")))]  # in call order
    assert len(results) == 0
    results.expect(session=2, response_id="r2", call_id="c")
    results.withdraw("c")
    results.response_done("r2")
    assert results.take_ready() == [] and len(results) == 0  # nothing left to send: dropped
