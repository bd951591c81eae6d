"""roslibpy (a stock rosbridge v2 client) calls services and sends goals through the real bridge,
with demo_robot as the real server: what roslibpy sends, the bridge understands, and the other way.

roslibpy runs a Twisted reactor that cannot restart in-process, so the client runs in a process of
its own: this file, run as a script (`python test_roslibpy_calls.py PORT NAMESPACE`), prints one
line per event.
"""

from __future__ import annotations

import json
import sys
import threading
from pathlib import Path
from typing import Any

if __name__ != "__main__":
    import pytest
    from byc_testing import running_process, wait_for
    from test_bridge_calls_graph import bridge, demo_robot, tools_file  # noqa: F401 - a fixture
    from test_bridge_node import Lines

    pytestmark = [pytest.mark.ros, pytest.mark.timeout(120)]

NAV_TYPE = "by_your_command_msgs/action/NavigateToPose"
WAIT_S = 30.0


def test_roslibpy_service_calls_and_goals(ros_namespace: str, tools_file: Path) -> None:
    with (
        demo_robot(ros_namespace, "speed_mps:=0.05", "feedback_rate_hz:=20.0"),
        bridge(ros_namespace, tools_file) as (port, _),
        running_process([sys.executable, __file__, str(port), ros_namespace]) as probe,
    ):
        lines = Lines(probe)
        wait_for(lambda: lines.ended.is_set(), timeout=100, what="the roslibpy client to finish")
        output = "\n".join(lines.lines)
        print(output)
        assert probe.wait(timeout=10) == 0, output
        events = [json.loads(line) for line in lines.lines if line.startswith("{")]
        by_kind: dict[str, dict[str, Any]] = {}
        for event in events:
            by_kind.setdefault(event["event"], event)  # the first of each: the cancelled goal's feedback
        assert by_kind["service"]["values"] == {"success": True, "message": "battery at 87%"}, output
        assert "not in the services allow-list" in by_kind["service_refused"]["error"], output
        assert by_kind["feedback"]["values"]["distance_remaining"] > 0, output
        assert by_kind["cancelled"]["status"] == "CANCELED", output
        assert by_kind["cancelled"]["values"]["error_msg"] == "cancelled", output
        assert by_kind["succeeded"]["status"] == "SUCCEEDED", output
        assert by_kind["rejected"]["status"] == "UNKNOWN", output


def _print(event: str, **fields: object) -> None:
    print(json.dumps({"event": event, **fields}, default=str), flush=True)


def _probe(port: int, namespace: str) -> None:
    import roslibpy

    ros = roslibpy.Ros("127.0.0.1", port)
    ros.run(timeout=10)
    try:
        # A service call: its response, then a refused call: its errback.
        battery = roslibpy.Service(ros, f"{namespace}/battery_status", "by_your_command_msgs/Trigger")
        _print("service", values=dict(battery.call(roslibpy.ServiceRequest({}), timeout=WAIT_S)))
        refused = threading.Event()

        def on_refused(error: object) -> None:
            _print("service_refused", error=str(error))
            refused.set()

        roslibpy.Service(ros, "not_a_tool", "std_srvs/Trigger").call(
            roslibpy.ServiceRequest({}), lambda _: None, on_refused
        )
        assert refused.wait(WAIT_S), "no errback for a refused call"

        action = roslibpy.ActionClient(ros, f"{namespace}/navigate_to_pose", NAV_TYPE)
        _goal(roslibpy, action, 10.0, "map", cancel=True)  # slow: feedback, then cancelled
        _goal(roslibpy, action, 0.0, "map", cancel=False)  # already there: succeeds
        _goal(roslibpy, action, 1.0, "odom", cancel=False)  # demo_robot refuses other frames
    finally:
        ros.terminate()


def _goal(roslibpy: object, action: object, x: float, frame: str, cancel: bool) -> None:
    ended = threading.Event()
    first_feedback = threading.Event()

    def on_result(result: dict[str, object]) -> None:
        status = result["status"]
        _print("cancelled" if cancel else "succeeded", status=status.name, values=result["values"])  # type: ignore[attr-defined]
        ended.set()

    def on_feedback(feedback: dict[str, object]) -> None:
        if not first_feedback.is_set():
            _print("feedback", values=dict(feedback))
            first_feedback.set()

    def on_error(error: dict[str, object]) -> None:
        status = error["status"]
        _print("rejected", status=status.name, values=error["values"])  # type: ignore[attr-defined]
        ended.set()

    goal = roslibpy.Goal({"pose": {"header": {"frame_id": frame}, "pose": {"position": {"x": x}}}})  # type: ignore[attr-defined]
    goal_id = action.send_goal(goal, on_result, on_feedback, on_error)  # type: ignore[attr-defined]
    if cancel:
        assert first_feedback.wait(WAIT_S), "no feedback"
        action.cancel_goal(goal_id)  # type: ignore[attr-defined]
    assert ended.wait(WAIT_S), "the goal never ended"


if __name__ == "__main__":
    _probe(int(sys.argv[1]), sys.argv[2])
