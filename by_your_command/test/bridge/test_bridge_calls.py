"""Service calls and action goals through BridgeCore (issue 35), with the scripted fake ROS graph.

Every refusal is a status to that client AND the call's failing reply (what roslibpy's errback
needs); outcomes are never dropped; feedback is latest-wins per goal and counted; goals of a client
that leaves, and on safety_stop every goal, are cancelled.
"""

from __future__ import annotations

import asyncio
import json
import threading
from dataclasses import replace
from typing import Any

import pytest
from bridge_fakes import NAMESPACE, eventually, make_core

from by_your_command.bridge.calls import CallOutcome
from by_your_command.bridge.config import BridgeParams, ConfigError, parse_allow_lists
from by_your_command.bridge.core import BridgeCore, ClientSession
from by_your_command.bridge.flow import SendQueue

pytestmark = pytest.mark.unit

SUCCEEDED, CANCELED, ABORTED = 4, 5, 6


def frames(session: ClientSession) -> list[dict[str, Any]]:
    out = []
    while (text := session.queue.take_nowait()) is not None:
        out.append(json.loads(text))
    return out


def call(service: str = "reset_pose", request_id: Any = "c1", **extra: Any) -> str:
    return json.dumps({"op": "call_service", "id": request_id, "service": service, "args": {}, **extra})


def goal(request_id: Any = "g1", action: str = "navigate", **extra: Any) -> str:
    frame = {
        "op": "send_action_goal",
        "id": request_id,
        "action": action,
        "action_type": "nav2_msgs/action/NavigateToPose",
        "args": {"pose": {}},
        "feedback": True,
    }
    return json.dumps({**frame, **extra})


def cancel(request_id: Any = "g1", action: str = "navigate") -> str:
    return json.dumps({"op": "cancel_action_goal", "id": request_id, "action": action})


def core_with(**overrides: Any) -> tuple[BridgeCore, Any, ClientSession]:
    core, graph = make_core(replace(BridgeParams(port=0), **overrides))
    return core, graph, core.open_session("agent")


# --- services -------------------------------------------------------------------------------------


def test_a_service_response_reaches_the_caller_with_its_id_and_values() -> None:
    core, graph, session = core_with()
    core.handle_frame(session, call(request_id=7, timeout=60))
    [made] = graph.calls
    assert (made.full_name, made.rule.type, made.request) == (
        f"{NAMESPACE}/reset_pose",
        "std_srvs/srv/Trigger",
        {"converted": {}},
    )
    assert made.timeout_s == 5.0  # the allow-list's bound wins over a longer client timeout
    assert graph.converted_calls[0].part == "request"
    assert frames(session) == []
    made.done(CallOutcome(True, '{"success":true,"message":"ok"}'))
    assert frames(session) == [
        {
            "op": "service_response",
            "service": "reset_pose",
            "id": 7,
            "values": {"success": True, "message": "ok"},
            "result": True,
        }
    ]
    totals = core.totals()
    assert (totals.service_calls, totals.service_failures, core.stats()[0].pending_calls) == (1, 0, 0)


def test_a_shorter_client_timeout_is_passed_on() -> None:
    core, graph, session = core_with()
    core.handle_frame(session, call("/global/set_flag", timeout=1.5))
    assert graph.calls[0].timeout_s == 1.5
    core.handle_frame(session, call("/global/set_flag", request_id="c2"))
    assert graph.calls[1].timeout_s == 10.0  # the allow-list's default


@pytest.mark.parametrize("code", ["no_server", "timeout", "internal_error"])
def test_a_failed_service_call_is_a_failing_response_with_its_code(code: str) -> None:
    core, graph, session = core_with()
    core.handle_frame(session, call())
    graph.calls[0].done(CallOutcome(False, error=f"it went wrong: {code}", code=code))
    assert frames(session) == [
        {
            "op": "service_response",
            "service": "reset_pose",
            "id": "c1",
            "values": f"it went wrong: {code}",
            "result": False,
            "code": code,
        }
    ]
    assert core.totals().service_failures == 1


@pytest.mark.parametrize(
    ("frame", "code"),
    [
        (call("not_listed"), "not_allowed"),
        (call(type="std_srvs/srv/SetBool"), "wrong_type"),
        (
            json.dumps({"op": "call_service", "id": "c1", "service": "reset_pose", "args": {"bad": 1}}),
            "bad_args",
        ),
    ],
)
def test_a_refused_call_gets_a_status_and_a_failing_response(frame: str, code: str) -> None:
    core, graph, session = core_with()
    core.handle_frame(session, frame)
    status, response = frames(session)
    assert (status["op"], status["level"], status["code"], status["id"]) == ("status", "error", code, "c1")
    assert response["op"] == "service_response" and response["id"] == "c1"
    assert (response["result"], response["code"], response["values"]) == (False, code, status["msg"])
    assert graph.calls == [] and session.rejected == 1


def test_a_malformed_call_with_an_id_is_answered_as_failed_too() -> None:
    core, graph, session = core_with()
    core.handle_frame(
        session, json.dumps({"op": "call_service", "id": 4, "service": "reset_pose", "args": [1]})
    )
    status, response = frames(session)
    assert status["code"] == "bad_request"
    assert (response["op"], response["id"], response["service"], response["code"]) == (
        "service_response",
        4,
        "reset_pose",
        "bad_args",
    )
    core.handle_frame(session, json.dumps({"op": "call_service", "service": "reset_pose"}))  # no id
    assert [f["op"] for f in frames(session)] == ["status"]


def test_pending_calls_per_client_are_bounded() -> None:
    core, graph, session = core_with(max_pending_calls=2)
    other = core.open_session("other")
    for index in range(3):
        core.handle_frame(session, call(request_id=index))
    assert len(graph.calls) == 2
    status, response = frames(session)
    assert status["code"] == response["code"] == "too_many" and response["id"] == 2
    core.handle_frame(other, call(request_id=0))  # per client: another client is not affected
    assert len(graph.calls) == 3
    graph.calls[0].done(CallOutcome(True))
    core.handle_frame(session, call(request_id=3))
    assert len(graph.calls) == 4


def test_an_error_in_the_graph_is_answered_and_does_not_leak_a_pending_call() -> None:
    core, graph, session = core_with(max_pending_calls=1)
    graph.fail_next = RuntimeError("rclpy exploded")
    core.handle_frame(session, call())
    status, response = frames(session)
    assert status["code"] == response["code"] == "internal_error" and response["id"] == "c1"
    assert session.pending_calls == 0
    core.handle_frame(session, call(request_id="c2"))
    assert len(graph.calls) == 1


def test_a_reply_larger_than_the_send_queue_becomes_a_failure_not_a_silent_loss() -> None:
    core, graph, session = core_with(send_queue_bytes=1000)
    core.handle_frame(session, call())
    graph.calls[0].done(CallOutcome(True, json.dumps({"message": "x" * 2000})))
    [response] = frames(session)
    assert (response["result"], response["code"], response["id"]) == (False, "too_large", "c1")


def test_replies_are_never_dropped_even_when_the_queue_is_full() -> None:
    core, graph, session = core_with(send_queue_messages=2)
    core.handle_frame(session, call())
    core.handle_frame(session, '{"op":"subscribe","topic":"prompt_text"}')
    for index in range(5):
        core.deliver(f"{NAMESPACE}/prompt_text", json.dumps({"data": str(index)}))
    graph.calls[0].done(CallOutcome(True, '{"success":true}'))
    ops = [f["op"] for f in frames(session)]
    assert ops.count("service_response") == 1 and ops.count("publish") == 2


def test_a_large_call_is_converted_on_a_worker_thread() -> None:
    async def scenario() -> None:
        core, graph, session = core_with(inline_convert_bytes=10)
        core.handle_frame(session, call(request_id="big"))
        await eventually(lambda: graph.calls, what="the call after its conversion")
        assert graph.converted_calls[0].thread != threading.get_ident()
        core.shutdown()

    asyncio.run(scenario())


# --- actions ----------------------------------------------------------------------------------------


def test_a_goal_gets_feedback_then_its_result() -> None:
    core, graph, session = core_with()
    core.handle_frame(session, goal())
    sent = graph.goal()
    assert (sent.full_name, sent.rule.type, graph.converted_calls[0].part) == (
        f"{NAMESPACE}/navigate",
        "nav2_msgs/action/NavigateToPose",
        "goal",
    )
    assert core.totals().goals_active == 1 and core.stats()[0].active_goals == 1
    sent.feedback('{"distance_remaining":3.5}')
    assert frames(session) == [
        {"op": "action_feedback", "action": "navigate", "id": "g1", "values": {"distance_remaining": 3.5}}
    ]
    sent.done(CallOutcome(True, '{"result":{}}', status=SUCCEEDED))
    assert frames(session) == [
        {
            "op": "action_result",
            "action": "navigate",
            "id": "g1",
            "values": {"result": {}},
            "status": 4,
            "result": True,
        }
    ]
    sent.feedback('{"distance_remaining":0}')  # late: the goal ended
    assert frames(session) == []
    totals = core.totals()
    assert (totals.goals_sent, totals.goals_active, totals.goals_succeeded) == (1, 0, 1)


def test_feedback_is_not_sent_unless_asked() -> None:
    core, graph, session = core_with()
    core.handle_frame(session, goal(feedback=False))
    graph.goal().feedback('{"distance_remaining":3.5}')
    assert frames(session) == []


def test_a_feedback_flood_is_latest_wins_per_goal_and_counted() -> None:
    core, graph, session = core_with()
    core.handle_frame(session, goal("a"))
    core.handle_frame(session, goal("b"))
    first, second = graph.goal(0), graph.goal(1)
    for index in range(1000):
        first.feedback(json.dumps({"n": index}))
    second.feedback('{"n":-1}')
    assert session.queue.depth == 2  # one per goal, whatever the flood
    assert frames(session) == [
        {"op": "action_feedback", "action": "navigate", "id": "a", "values": {"n": 999}},
        {"op": "action_feedback", "action": "navigate", "id": "b", "values": {"n": -1}},
    ]
    assert core.stats()[0].feedback_dropped == 999
    first.feedback('{"n":1000}')
    first.done(CallOutcome(True, "{}", status=SUCCEEDED))  # its queued feedback goes: never after the result
    assert [f["op"] for f in frames(session)] == ["action_result"]
    core.close_session(session)
    assert core.totals().feedback_dropped == 1000


def test_a_full_queue_drops_new_feedback_and_counts_it() -> None:
    core, graph, session = core_with(send_queue_messages=1)
    core.handle_frame(session, '{"op":"subscribe","topic":"prompt_text"}')
    core.deliver(f"{NAMESPACE}/prompt_text", '{"data":"fills the queue"}')
    core.handle_frame(session, goal())
    graph.goal().feedback("{}")
    assert session.queue.feedback_dropped == 1
    assert [f["op"] for f in frames(session)] == ["publish"]


def test_a_rejected_goal_and_a_goal_without_server_fail_with_a_status() -> None:
    core, graph, session = core_with()
    core.handle_frame(session, goal("r"))
    core.handle_frame(session, goal("n"))
    graph.goal(0).done(CallOutcome(False, error="goal rejected", code="rejected", status=0))
    graph.goal(1).done(CallOutcome(False, error="no action server /robot1/navigate", code="no_server"))
    rejected, missing = frames(session)
    assert (rejected["result"], rejected["status"], rejected["values"], rejected["code"]) == (
        False,
        0,
        "goal rejected",
        "rejected",
    )
    assert (missing["status"], missing["code"]) == (ABORTED, "no_server")  # never "unknown" unless rejected
    assert core.totals().goals_failed == 2


@pytest.mark.parametrize(
    ("frame", "code"),
    [
        (goal(action="elsewhere"), "not_allowed"),
        (goal(action_type="nav2_msgs/action/Spin"), "wrong_type"),
        (goal(args={"bad": True}), "bad_args"),
    ],
)
def test_a_refused_goal_gets_a_status_and_a_failing_result(frame: str, code: str) -> None:
    core, graph, session = core_with()
    core.handle_frame(session, frame)
    status, result = frames(session)
    assert (status["code"], status["id"]) == (code, "g1")
    assert (result["op"], result["id"], result["result"], result["status"], result["code"]) == (
        "action_result",
        "g1",
        False,
        ABORTED,
        code,
    )
    assert graph.goals == {}


def test_active_goals_per_client_are_bounded_and_ids_unique() -> None:
    core, graph, session = core_with(max_active_goals=2)
    core.handle_frame(session, goal("a"))
    core.handle_frame(session, goal("a"))
    status, result = frames(session)
    assert status["code"] == "bad_request" and "still active" in status["msg"] and result["id"] == "a"
    core.handle_frame(session, goal("b"))
    core.handle_frame(session, goal("c"))
    assert [f["code"] for f in frames(session)] == ["too_many", "too_many"]
    assert len(graph.goals) == 2
    graph.goal(0).done(CallOutcome(True, "{}", status=SUCCEEDED))
    frames(session)
    core.handle_frame(session, goal("c"))
    assert len(graph.goals) == 3


def test_cancel_by_the_goal_requests_id() -> None:
    core, graph, session = core_with()
    core.handle_frame(session, goal("g1"))
    core.handle_frame(session, goal("g2"))
    core.handle_frame(session, cancel("g2"))
    assert [g.cancels for g in graph.goals.values()] == [0, 1]
    assert frames(session) == []  # the answer is the goal's result, when the server confirms
    graph.goal(1).done(CallOutcome(True, "{}", status=CANCELED))
    [result] = frames(session)
    assert (result["id"], result["status"], result["result"]) == ("g2", CANCELED, True)
    assert core.totals().goals_cancelled == 1


@pytest.mark.parametrize("frame", [cancel("nope"), cancel("g1", action="other"), cancel(1)])
def test_cancelling_an_unknown_goal_is_a_warning_not_active(frame: str) -> None:
    core, graph, session = core_with()
    core.handle_frame(session, goal("g1"))
    core.handle_frame(session, frame)
    [status] = frames(session)  # no action_result: that would end the client's goal g1
    assert (status["op"], status["level"], status["code"]) == ("status", "warning", "not_active")
    assert graph.goal().cancels == 0


def test_a_client_cannot_cancel_another_clients_goal() -> None:
    core, graph, session = core_with()
    other = core.open_session("other")
    core.handle_frame(session, goal("g1"))
    core.handle_frame(other, cancel("g1"))
    assert frames(other)[0]["code"] == "not_active" and graph.goal().cancels == 0


def test_cancel_all_goals_stops_every_clients_goals_and_says_why() -> None:
    core, graph, session = core_with()
    other = core.open_session("other")
    core.handle_frame(session, goal("g1"))
    core.handle_frame(other, goal("g1"))
    assert core.cancel_all_goals("safety_stop: the user said stop") == 2
    assert [g.cancels for g in graph.goals.values()] == [1, 1]
    graph.goal(0).done(CallOutcome(False, error="cancelled", code="cancelled", status=CANCELED))
    [result] = frames(session)
    assert result["values"] == "cancelled (safety_stop: the user said stop)" and result["status"] == CANCELED
    assert core.cancel_all_goals("again") == 1  # only what is still active
    graph.goal(1).done(CallOutcome(True, "{}", status=CANCELED))
    assert core.cancel_all_goals("nothing left") == 0
    assert core.totals().goals_cancelled == 2


def test_a_departing_client_has_its_goals_cancelled_and_its_outcomes_counted_not_sent() -> None:
    core, graph, session = core_with()
    core.handle_frame(session, goal("g1"))
    core.handle_frame(session, call())
    core.close_session(session)
    assert graph.goal().cancels == 1
    assert core.totals().goals_active == 1  # until ROS confirms
    graph.goal().done(CallOutcome(True, "{}", status=CANCELED))
    graph.calls[0].done(CallOutcome(True, "{}"))
    assert session.queue.take_nowait() is None
    totals = core.totals()
    assert (totals.goals_active, totals.replies_discarded, totals.goals_cancelled) == (0, 2, 1)


def test_a_second_outcome_for_a_goal_is_ignored() -> None:
    core, graph, session = core_with()
    core.handle_frame(session, goal())
    graph.goal().done(CallOutcome(True, "{}", status=SUCCEEDED))
    graph.goal().done(CallOutcome(False, error="again", code="internal_error"))
    assert [f["op"] for f in frames(session)] == ["action_result"]
    assert core.totals().goals_succeeded == 1 and core.totals().goals_failed == 0


def test_a_not_active_answer_cannot_overtake_the_result_it_concerns() -> None:
    """The goal ended (its result is queued) just before the client's cancel arrived."""
    core, graph, session = core_with()
    core.handle_frame(session, goal())
    graph.goal().done(CallOutcome(True, "{}", status=SUCCEEDED))
    core.handle_frame(session, cancel())
    assert [f["op"] for f in frames(session)] == ["action_result", "status"]


# --- roslibpy 2.1 understands every answer ---------------------------------------------------------


def test_roslibpy_callbacks_and_errbacks_fire_on_our_frames() -> None:
    comm = pytest.importorskip("roslibpy.comm.comm")
    protocol = comm.RosBridgeProtocol()
    seen: list[tuple[str, Any]] = []

    def handlers(name: str) -> tuple[Any, Any]:
        return (
            lambda value: seen.append((f"{name} ok", value)),
            lambda error: seen.append((f"{name} err", error)),
        )

    core, graph, session = core_with()
    core.handle_frame(session, call(request_id="s1"))
    core.handle_frame(session, call("not_listed", request_id="s2"))
    core.handle_frame(session, goal("g1"))
    core.handle_frame(session, goal("g2", action="elsewhere"))
    protocol._pending_service_requests = {"s1": handlers("s1"), "s2": handlers("s2")}
    ok1, err1 = handlers("g1")
    ok2, err2 = handlers("g2")
    protocol._pending_action_requests = {
        "g1": (ok1, lambda feedback: seen.append(("g1 feedback", feedback)), err1),
        "g2": (ok2, None, err2),
    }

    def deliver_to_roslibpy() -> None:
        for frame in frames(session):
            if frame["op"] != "status":  # roslibpy 2.1 has no handler for status (it is None)
                protocol.on_message(json.dumps(frame).encode())

    graph.calls[0].done(CallOutcome(True, '{"success":true}'))
    graph.goal().feedback('{"distance_remaining":1.0}')
    deliver_to_roslibpy()
    graph.goal().done(CallOutcome(True, '{"ok":1}', status=SUCCEEDED))
    deliver_to_roslibpy()
    names = [name for name, _ in seen]
    assert sorted(names) == ["g1 feedback", "g1 ok", "g2 err", "s1 ok", "s2 err"]
    assert dict(seen)["s1 ok"] == {"success": True}
    assert "not in the services allow-list" in dict(seen)["s2 err"]
    assert dict(seen)["g2 err"]["status"].value == ABORTED


# --- allow-lists and parameters ---------------------------------------------------------------------


def test_services_and_actions_sections_are_validated() -> None:
    allow = parse_allow_lists(
        {
            "services": [{"name": "/x", "type": "std_srvs/Trigger", "timeout_s": 2}],
            "actions": [{"name": "nav", "type": "nav2_msgs/NavigateToPose"}],
        }
    )
    assert (allow.services[0].type, allow.services[0].timeout_s) == ("std_srvs/srv/Trigger", 2.0)
    assert (allow.actions[0].type, allow.actions[0].timeout_s) == ("nav2_msgs/action/NavigateToPose", 10.0)
    for bad, fragment in [
        ({"services": [{"name": "/x"}]}, "non-empty strings"),
        ({"services": [{"name": "/x", "type": "std_msgs/msg/String"}]}, "invalid srv type"),
        ({"actions": [{"name": "/x", "type": "a/srv/B"}]}, "invalid action type"),
        ({"services": [{"name": "a b", "type": "a/B"}]}, "invalid topic name"),
        ({"services": [{"name": "/x", "type": "a/B", "timeout_s": 0}]}, "timeout_s"),
        ({"services": [{"name": "/x", "type": "a/B", "timeout_s": float("nan")}]}, "timeout_s"),
        ({"services": [{"name": "/x", "type": "a/B", "timeout_s": True}]}, "timeout_s"),
        ({"actions": [{"name": "/x", "type": "a/B", "retries": 3}]}, "unknown keys"),
        ({"services": [{"name": "/x", "type": "a/B"}, {"name": "/x", "type": "a/B"}]}, "more than once"),
        ({"services": {"name": "/x"}}, "must be a list"),
    ]:
        with pytest.raises(ConfigError, match=fragment):
            parse_allow_lists(bad)


def test_merged_allow_lists_union_and_refuse_conflicts() -> None:
    ours = parse_allow_lists(
        {
            "publish": [{"topic": "cmd", "type": "std_msgs/String"}],
            "services": [{"name": "/x", "type": "a/B"}],
        }
    )
    tools = parse_allow_lists(
        {
            "publish": [{"topic": "cmd", "type": "std_msgs/String"}, {"topic": "vel", "type": "a/Twist"}],
            "services": [{"name": "/x", "type": "a/srv/B", "timeout_s": 60}],
            "actions": [{"name": "/go", "type": "a/Go"}],
        }
    )
    merged = ours.merged(tools)
    assert [r.topic for r in merged.publish] == ["cmd", "vel"]
    assert [(r.name, r.timeout_s) for r in merged.services] == [("/x", 60.0)]
    assert [r.name for r in merged.actions] == ["/go"]
    with pytest.raises(ConfigError, match="two types"):
        ours.merged(parse_allow_lists({"services": [{"name": "/x", "type": "a/C"}]}))
    with pytest.raises(ConfigError, match="different settings"):
        ours.merged(parse_allow_lists({"publish": [{"topic": "cmd", "type": "std_msgs/Bool"}]}))


def test_two_names_resolving_to_one_service_with_two_types_are_refused() -> None:
    allow = parse_allow_lists(
        {"services": [{"name": "x", "type": "a/B"}, {"name": f"{NAMESPACE}/x", "type": "a/C"}]}
    )
    with pytest.raises(ConfigError, match="two types"):
        make_core(allow=allow)


@pytest.mark.parametrize("name", ["max_pending_calls", "max_active_goals"])
def test_call_bounds_must_be_positive(name: str) -> None:
    with pytest.raises(ValueError, match=name):
        BridgeParams(**{name: 0})


def test_the_reply_lane_counts_towards_the_byte_bound_so_data_yields() -> None:
    queue = SendQueue(max_messages=10, max_bytes=100)
    queue.put_reply("r" * 90)
    assert not queue.put("x" * 20, "/audio", False, 10)
    assert json.loads(queue.take_nowait() or "")["code"] == "dropped"
    assert queue.take_nowait() == "r" * 90 and queue.queued_bytes == 0
