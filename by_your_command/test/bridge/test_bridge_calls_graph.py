"""Service calls and action goals through the real bridge node, with demo_robot as the real server.

Both run as processes in a namespace of their own; clients are plain WebSocket clients speaking
rosbridge v2 (call_service, send_action_goal, cancel_action_goal).
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from by_your_command_msgs.msg import SafetyStop
from byc_testing import INSTALL_LIB, running_process, wait_for
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from std_msgs.msg import String
from test_bridge_node import Lines, Reader, bridge_process
from websockets.sync.client import connect

from by_your_command.nodes import _qos
from by_your_command.ros.convert import ConversionError, from_dict, part_class, to_json

pytestmark = [pytest.mark.ros, pytest.mark.timeout(120)]

NAV_TYPE = "by_your_command_msgs/action/NavigateToPose"
TRIGGER_TYPE = "by_your_command_msgs/srv/Trigger"
SUCCEEDED, CANCELED = 4, 5


def tools_yaml(namespace: str, go_to_timeout_s: float = 5.0) -> str:
    """A tools file (docs/tools.md) naming demo_robot's interfaces in this test's namespace."""
    return f"""
tools:
  go_to:
    description: Drive to one of the named places and stop there.
    action: {namespace}/navigate_to_pose
    type: {NAV_TYPE}
    fixed: {{pose.header.frame_id: map}}
    arguments:
      place:
        description: where to go
        choices:
          kitchen: {{pose.pose.position.x: 1.0, pose.pose.orientation.w: 1.0}}
    feedback: {{every_s: 1, fields: [distance_remaining]}}
    timeout_s: {go_to_timeout_s}
  dock:
    description: Drive onto the charging dock.
    service: {namespace}/dock
    type: {TRIGGER_TYPE}
  battery:
    description: Say how full the battery is.
    service: {namespace}/battery_status
    type: {TRIGGER_TYPE}
    timeout_s: 5
  ghost_service:
    description: A service nobody serves.
    service: {namespace}/nobody_serves_this
    type: {TRIGGER_TYPE}
    timeout_s: 1
  ghost_drive:
    description: An action nobody serves.
    action: {namespace}/nobody_drives
    type: {NAV_TYPE}
    timeout_s: 1
  look:
    description: Turn the head.
    command: "pan@{{direction}}"
    arguments: {{direction: {{choices: [left, right]}}}}
"""


@pytest.fixture
def tools_file(tmp_path: Path, ros_namespace: str) -> Path:
    path = tmp_path / "tools.yaml"
    path.write_text(tools_yaml(ros_namespace), encoding="utf-8")
    return path


@contextmanager
def demo_robot(namespace: str, *params: str) -> Iterator[Lines]:
    args = [str(INSTALL_LIB / "demo_robot"), "--ros-args", "-r", f"__ns:={namespace}"]
    for param in params:
        args += ["-p", param]
    with running_process(args) as process:
        lines = Lines(process)
        wait_for(
            lambda: lines.find("demo_robot ready") or process.poll() is not None,
            timeout=20,
            what="demo_robot startup",
        )
        assert lines.find("demo_robot ready"), "\n".join(lines.lines)
        yield lines


@contextmanager
def bridge(namespace: str, tools: Path, *params: str) -> Iterator[tuple[int, Lines]]:
    with bridge_process(namespace, params=(f"tools_path:={tools}", *params)) as (_, port, lines):
        yield port, lines


@contextmanager
def client(port: int) -> Iterator[Reader]:
    reader = Reader(port)
    try:
        yield reader
    finally:
        reader.close()


def frames_of(reader: Reader, op: str, request_id: object) -> list[dict[str, Any]]:
    return [f for f in list(reader.frames) if f.get("op") == op and f.get("id") == request_id]


def answer(reader: Reader, op: str, request_id: object, timeout: float = 30) -> dict[str, Any]:
    found = wait_for(
        lambda: frames_of(reader, op, request_id), timeout=timeout, what=f"{op} for {request_id}"
    )
    assert len(found) == 1, found  # exactly one answer per call or goal
    first: dict[str, Any] = found[0]
    return first


def diagnostics_of(node: Node) -> list[DiagnosticArray]:
    reports: list[DiagnosticArray] = []
    node.create_subscription(DiagnosticArray, "/diagnostics", reports.append, _qos.RELIABLE)
    return reports


def server_seen(reports: list[DiagnosticArray], namespace: str, name: str) -> None:
    """Wait until the bridge sees the server of `name` (its diagnostics' servers.<name> is 1)."""
    key = f"servers.{namespace}/{name}"
    wait_for(
        lambda: any(d.get(key) == "1" for d in diagnostics(reports, namespace)),
        timeout=30,
        what=f"the bridge sees the server of {name}",
    )


def diagnostics(reports: list[DiagnosticArray], namespace: str) -> list[dict[str, str]]:
    return [
        {kv.key: kv.value for kv in status.values}
        for array in list(reports)
        for status in array.status
        if status.name.startswith(f"{namespace}/ros_ai_bridge: websocket")
    ]


def goal(namespace: str, request_id: object, x: float, frame: str = "map") -> dict[str, Any]:
    return {
        "op": "send_action_goal",
        "id": request_id,
        "action": f"{namespace}/navigate_to_pose",
        "action_type": NAV_TYPE,
        "args": {"pose": {"header": {"frame_id": frame}, "pose": {"position": {"x": x}}}},
        "feedback": True,
    }


def test_service_and_action_parts_convert() -> None:
    goal_class = part_class("by_your_command_msgs/NavigateToPose", "goal")  # pkg/T is accepted too
    built = from_dict(goal_class, {"pose": {"header": {"frame_id": "map"}, "pose": {"position": {"x": 2.5}}}})
    assert built.pose.pose.position.x == 2.5 and built.pose.header.frame_id == "map"
    feedback = part_class(NAV_TYPE, "feedback")(distance_remaining=float("nan"), number_of_recoveries=2)
    assert json.loads(to_json(feedback))["distance_remaining"] is None  # JSON has no NaN
    response = part_class(TRIGGER_TYPE, "response")(success=True, message="docked")
    assert to_json(response) == '{"success":true,"message":"docked"}'
    assert part_class(TRIGGER_TYPE, "request").get_fields_and_field_types() == {}
    for bad, part, says in (
        ("std_msgs/msg/String", "request", "invalid srv type"),
        ("by_your_command_msgs/srv/NoSuchThing", "request", "not installed"),
        (TRIGGER_TYPE, "goal", "invalid action type"),
    ):
        with pytest.raises(ConversionError, match=says):
            part_class(bad, part)  # type: ignore[arg-type]


def test_goal_succeeds_with_feedback_and_a_service_answers(ros_namespace: str, tools_file: Path) -> None:
    with (
        demo_robot(ros_namespace, "speed_mps:=1.0", "feedback_rate_hz:=20.0"),
        bridge(ros_namespace, tools_file) as (port, _),
        client(port) as reader,
    ):
        reader.send(goal(ros_namespace, "g1", 0.5))
        result = answer(reader, "action_result", "g1")
        assert result["result"] is True and result["status"] == SUCCEEDED, result
        assert result["values"] == {"error_code": 0, "error_msg": ""}
        assert result["action"] == f"{ros_namespace}/navigate_to_pose"
        feedback = frames_of(reader, "action_feedback", "g1")
        assert feedback, "no feedback before the result"
        assert 0 <= feedback[-1]["values"]["distance_remaining"] <= 0.5
        assert reader.frames.index(feedback[-1]) < reader.frames.index(result)  # never after the result

        reader.send({"op": "call_service", "id": 7, "service": "battery_status", "type": TRIGGER_TYPE})
        response = answer(reader, "service_response", 7)
        assert response == {
            "op": "service_response",
            "service": "battery_status",
            "id": 7,
            "values": {"success": True, "message": "battery at 87%"},
            "result": True,
        }


def test_rejected_goal_and_refused_arguments(ros_namespace: str, tools_file: Path) -> None:
    with demo_robot(ros_namespace), bridge(ros_namespace, tools_file) as (port, _), client(port) as reader:
        reader.send(goal(ros_namespace, "odom", 1.0, frame="odom"))  # demo_robot drives in map only
        rejected = answer(reader, "action_result", "odom")
        assert rejected["result"] is False and rejected["status"] == 0, rejected
        assert rejected["code"] == "rejected" and "rejected" in rejected["values"]

        bad = goal(ros_namespace, "bad", 1.0)
        bad["args"] = {"pose": {"pose": {"position": {"x": "far"}}}}
        reader.send(bad)  # refused by the bridge's conversion, before ROS
        refused = answer(reader, "action_result", "bad")
        assert refused["result"] is False and refused["code"] == "bad_args", refused
        assert "pose.pose.position.x" in refused["values"]


def test_cancel_by_id(ros_namespace: str, tools_file: Path) -> None:
    with (
        demo_robot(ros_namespace, "speed_mps:=0.05", "feedback_rate_hz:=20.0") as robot,
        bridge(ros_namespace, tools_file) as (port, _),
        client(port) as reader,
    ):
        reader.send(goal(ros_namespace, 42, 10.0))
        wait_for(lambda: frames_of(reader, "action_feedback", 42), timeout=20, what="first feedback")
        reader.send({"op": "cancel_action_goal", "id": 42, "action": f"{ros_namespace}/navigate_to_pose"})
        result = answer(reader, "action_result", 42)
        assert result["result"] is True and result["status"] == CANCELED, result
        assert result["values"]["error_msg"] == "cancelled"
        assert robot.find("goal cancelled")


def test_a_cancel_before_the_acceptance_is_applied_at_the_acceptance(
    ros_namespace: str, tools_file: Path
) -> None:
    with (
        demo_robot(ros_namespace, "speed_mps:=0.05", "accept_delay_s:=2.0") as robot,
        bridge(ros_namespace, tools_file) as (port, _),
        client(port) as reader,
    ):
        reader.send(goal(ros_namespace, "early", 10.0))
        wait_for(
            lambda: robot.find("answering a goal request"), timeout=20, what="the goal reaches the robot"
        )
        reader.send(
            {"op": "cancel_action_goal", "id": "early", "action": f"{ros_namespace}/navigate_to_pose"}
        )
        result = answer(reader, "action_result", "early")
        assert result["result"] is True and result["status"] == CANCELED, result
        assert robot.find("goal cancelled")


def test_a_goal_accepted_too_late_is_cancelled(ros_namespace: str, tmp_path: Path, graph_node: Node) -> None:
    reports = diagnostics_of(graph_node)
    tools = tmp_path / "tools.yaml"
    tools.write_text(tools_yaml(ros_namespace, go_to_timeout_s=1.0), encoding="utf-8")
    with (
        demo_robot(ros_namespace, "speed_mps:=0.05", "accept_delay_s:=3.0") as robot,
        bridge(ros_namespace, tools) as (port, _),
        client(port) as reader,
    ):
        server_seen(reports, ros_namespace, "navigate_to_pose")  # the 1 s is for the acceptance
        reader.send(goal(ros_namespace, "late", 10.0))
        result = answer(reader, "action_result", "late")
        assert result["result"] is False and result["code"] == "timeout", result
        # Nobody waits for it any more: once the robot accepts it, the bridge cancels it.
        wait_for(lambda: robot.find("goal cancelled"), timeout=20, what="the late goal cancelled")
        assert not frames_of(reader, "action_feedback", "late")


def test_a_stopping_bridge_cancels_its_goals(ros_namespace: str, tools_file: Path) -> None:
    with (
        demo_robot(ros_namespace, "speed_mps:=0.05", "feedback_rate_hz:=20.0") as robot,
        bridge_process(ros_namespace, params=(f"tools_path:={tools_file}",)) as (process, port, lines),
    ):
        with client(port) as reader:
            reader.send(goal(ros_namespace, "running", 10.0))
            wait_for(
                lambda: frames_of(reader, "action_feedback", "running"), timeout=20, what="the goal runs"
            )
            process.send_signal(signal.SIGINT)
            assert process.wait(timeout=30) == 0, "\n".join(lines.lines)
        wait_for(lambda: robot.find("goal cancelled"), timeout=20, what="the robot stops")


def test_missing_servers_and_a_service_timeout(
    ros_namespace: str, tools_file: Path, graph_node: Node
) -> None:
    reports = diagnostics_of(graph_node)
    with (
        demo_robot(ros_namespace, "service_delay_s:=30.0"),
        bridge(ros_namespace, tools_file) as (port, _),
        client(port) as reader,
    ):
        server_seen(reports, ros_namespace, "battery_status")  # the 1 s is for the answer
        reader.send({"op": "call_service", "id": "ghost", "service": "nobody_serves_this"})
        reader.send(
            {
                "op": "send_action_goal",
                "id": "ghost",
                "action": "nobody_drives",
                "action_type": NAV_TYPE,
                "args": {},
            }
        )
        reader.send({"op": "call_service", "id": "slow", "service": "battery_status", "timeout": 1})
        missing = answer(reader, "service_response", "ghost")
        assert missing["result"] is False and missing["code"] == "no_server", missing
        no_driver = answer(reader, "action_result", "ghost")
        assert no_driver["result"] is False and no_driver["code"] == "no_server", no_driver
        assert no_driver["status"] == 6  # ABORTED: it never ran
        slow = answer(reader, "service_response", "slow")
        assert slow["result"] is False and slow["code"] == "timeout", slow


def test_safety_stop_cancels_every_goal(ros_namespace: str, tools_file: Path, graph_node: Node) -> None:
    stop = graph_node.create_publisher(SafetyStop, "safety_stop", _qos.RELIABLE)
    with (
        demo_robot(ros_namespace, "speed_mps:=0.05", "feedback_rate_hz:=20.0"),
        bridge(ros_namespace, tools_file) as (port, lines),
        client(port) as reader,
    ):
        wait_for(lambda: stop.get_subscription_count() >= 1, timeout=20, what="bridge subscribes safety_stop")
        reader.send(goal(ros_namespace, "walk", 10.0))
        wait_for(lambda: frames_of(reader, "action_feedback", "walk"), timeout=20, what="the goal runs")
        stop.publish(SafetyStop(phrase="stop"))
        result = answer(reader, "action_result", "walk")
        assert result["status"] == CANCELED, result
        wait_for(lambda: lines.find(r"safety stop \('stop'\): cancelled 1 goal"), timeout=10, what="log line")


def test_a_client_that_leaves_has_its_goal_cancelled(ros_namespace: str, tools_file: Path) -> None:
    with (
        demo_robot(ros_namespace, "speed_mps:=0.05", "feedback_rate_hz:=20.0") as robot,
        bridge(ros_namespace, tools_file) as (port, _),
    ):
        with client(port) as reader:
            reader.send(goal(ros_namespace, "left behind", 10.0))
            wait_for(
                lambda: frames_of(reader, "action_feedback", "left behind"), timeout=20, what="the goal runs"
            )
        wait_for(lambda: robot.find("goal cancelled"), timeout=20, what="the robot stops")


@pytest.mark.timeout(240)  # the kernel's socket buffers (megabytes) fill first
def test_a_feedback_flood_to_a_client_that_does_not_read_stays_bounded(
    ros_namespace: str, tools_file: Path, graph_node: Node
) -> None:
    reports = diagnostics_of(graph_node)
    with (
        demo_robot(ros_namespace, "speed_mps:=0.01", "feedback_rate_hz:=500.0"),
        bridge(ros_namespace, tools_file) as (port, _),
    ):
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # the client's kernel buffer fills fast
        sock.connect(("127.0.0.1", port))
        with connect(f"ws://127.0.0.1:{port}/", sock=sock, compression=None) as connection:
            connection.send(json.dumps(goal(ros_namespace, "flood", 10.0)))

            def dropped() -> bool:
                return any(
                    int(d.get("feedback_dropped_total", 0)) > 0 for d in diagnostics(reports, ros_namespace)
                )

            wait_for(
                dropped, timeout=150, interval=0.1, what="feedback replaced while the client does not read"
            )
            depths = [
                int(v)
                for d in diagnostics(reports, ros_namespace)
                for k, v in d.items()
                if k.endswith(".queue_depth")
            ]
            assert depths and max(depths) <= 4, depths  # one feedback slot per goal, whatever the flood
            connection.send(
                json.dumps(
                    {"op": "cancel_action_goal", "id": "flood", "action": f"{ros_namespace}/navigate_to_pose"}
                )
            )
            seen = {"feedback": 0}
            while True:  # now read: everything queued arrives, the result last
                frame = json.loads(connection.recv(timeout=30))
                if frame["op"] == "action_feedback":
                    seen["feedback"] += 1
                    continue
                assert frame["op"] == "action_result" and frame["id"] == "flood", frame
                assert frame["status"] == CANCELED
                break
            last = diagnostics(reports, ros_namespace)[-1]
            print(
                f"feedback: {seen['feedback']} read, {last['feedback_dropped_total']} replaced in the "
                f"client's queue, {last['feedback_coalesced_total']} before the loop; "
                f"queue depth at most {max(depths)}"
            )


def test_robot_tools_are_published_and_allow_listed(
    ros_namespace: str, tools_file: Path, graph_node: Node
) -> None:
    catalogs: list[String] = []
    graph_node.create_subscription(String, "robot_tools", catalogs.append, _qos.LATCHED)
    with bridge(ros_namespace, tools_file) as (port, _), client(port) as reader:
        wait_for(lambda: catalogs, timeout=20, what="the latched catalog")
        catalog = json.loads(catalogs[0].data)
        tools = {tool["name"]: tool for tool in catalog["tools"]}
        assert set(tools) == {"go_to", "dock", "battery", "ghost_service", "ghost_drive", "look"}
        assert tools["go_to"]["kind"] == "action" and tools["go_to"]["type"] == NAV_TYPE
        assert tools["go_to"]["ros_name"] == f"{ros_namespace}/navigate_to_pose"
        assert tools["go_to"]["parameters"]["properties"]["place"]["enum"] == ["kitchen"]
        assert tools["look"]["kind"] == "command"
        # Clients get it through the bridge too (state: the last value to a late subscriber).
        reader.send({"op": "subscribe", "topic": "robot_tools"})
        published = wait_for(
            lambda: [f for f in list(reader.frames) if f.get("topic") == "robot_tools"],
            timeout=20,
            what="relay",
        )
        assert json.loads(published[0]["msg"]["data"]) == catalog
        # A service of bridge.yaml's own that no tool names is not callable.
        reader.send({"op": "call_service", "id": 1, "service": "some_other_service"})
        refused = answer(reader, "service_response", 1)
        assert refused["result"] is False and refused["code"] == "not_allowed"


def test_a_bad_tools_file_stops_the_start(ros_namespace: str, tmp_path: Path) -> None:
    bad = tmp_path / "tools.yaml"
    bad.write_text(tools_yaml(ros_namespace).replace(NAV_TYPE, "by_your_command_msgs/action/NoSuchThing", 1))
    args = [
        str(INSTALL_LIB / "ros_ai_bridge"),
        "--ros-args",
        "-r",
        f"__ns:={ros_namespace}",
        "-p",
        "port:=0",
        "-p",
        f"tools_path:={bad}",
    ]
    result = subprocess.run(args, capture_output=True, text=True, timeout=60)
    output = result.stdout + result.stderr
    assert result.returncode != 0, output
    assert str(bad) in output and "go_to" in output, output
