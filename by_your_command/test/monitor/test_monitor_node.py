"""The real ros_ai_bridge node summarises agent_metrics (published by an agent through the bridge)
into /diagnostics and the latched agent_summary topic."""

from __future__ import annotations

import json
import re
import threading
from typing import Any

import pytest
from byc_testing import INSTALL_LIB, running_process, wait_for
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from ros_probe import probe_node
from std_msgs.msg import String
from websockets.sync.client import connect

from by_your_command.agents.events import Usage
from by_your_command.agents.metrics import SessionMetrics, TurnMetrics
from by_your_command.nodes import _qos

pytestmark = [pytest.mark.ros, pytest.mark.timeout(120)]


def test_agent_metrics_become_diagnostics_and_a_latched_summary(ros_namespace: str) -> None:
    args = [str(INSTALL_LIB / "ros_ai_bridge"), "--ros-args", "-r", f"__ns:={ros_namespace}"]
    args += ["-p", "port:=0", "-p", "diagnostics_period_s:=0.2", "-p", "summary_period_s:=0.2"]
    with running_process(args) as bridge, probe_node(ros_namespace) as probe:
        output: list[str] = []
        assert bridge.stdout is not None
        threading.Thread(target=lambda: output.extend(bridge.stdout or []), daemon=True).start()
        found = wait_for(
            lambda: next(
                (m for line in list(output) if (m := re.search(r"listening on 127\.0\.0\.1:(\d+)", line))),
                None,
            ),
            timeout=30,
            what="bridge startup",
        )
        port = int(found.group(1))
        diagnostics: list[Any] = probe.listen(DiagnosticArray, "/diagnostics", _qos.RELIABLE)
        records = [
            TurnMetrics(
                "robot",
                "c1",
                1,
                1,
                "voice",
                "completed",
                240.0,
                900.0,
                Usage(input_audio_tokens=1000),
                "gemini_live",
            ),
            SessionMetrics(
                "robot",
                "c1",
                1,
                30.0,
                1,
                "pause of 2 s",
                Usage(input_audio_tokens=1200, output_audio_tokens=500),
                "gemini_live",
            ),
        ]
        with connect(f"ws://127.0.0.1:{port}/") as agent:  # what an agent's BridgeClient sends
            agent.send(
                json.dumps({"op": "advertise", "topic": "agent_metrics", "type": "std_msgs/msg/String"})
            )
            for text in ("not a record", *(json.dumps(r.as_dict()) for r in records)):
                agent.send(json.dumps({"op": "publish", "topic": "agent_metrics", "msg": {"data": text}}))

            def agent_status() -> DiagnosticStatus | None:
                probe.spin(0.05)
                for array in reversed(diagnostics):
                    named = {s.name: s for s in array.status}
                    status = named.get(f"{ros_namespace}/ros_ai_bridge: agent robot")
                    overall = named.get(f"{ros_namespace}/ros_ai_bridge: agents")
                    if status is not None and overall is not None and "idle" in status.message:
                        values = {kv.key: kv.value for kv in overall.values}
                        if values["agents_connected"] == "1" and values["invalid_records"] == "1":
                            return status
                return None

            status = wait_for(agent_status, timeout=60, what="the agent's diagnostics")
            values = {kv.key: kv.value for kv in status.values}
            assert status.level == DiagnosticStatus.OK
            assert (values["provider"], values["sessions"], values["billed_s"]) == (
                "gemini_live",
                "1",
                "30.0",
            )
            assert (values["input_tokens"], values["output_tokens"]) == ("1200", "500")
            assert float(values["cost"]) == pytest.approx(
                (1200 * 3.0 + 500 * 12.0) / 1e6
            )  # config/monitor.yaml

        # A late subscriber (rqt, Foxglove, the page) gets the summary at once: it is latched.
        with probe_node(ros_namespace, "late") as late:
            summaries: list[Any] = late.listen(String, "agent_summary", _qos.LATCHED)
            wait_for(lambda: late.spin(0.05) or summaries, timeout=30, what="the latched summary")
            summary = json.loads(summaries[-1].data)
            assert summary["providers"][0]["provider"] == "gemini_live"
            assert summary["agents"][0]["state"] == "idle" and summary["invalid_records"] == 1
