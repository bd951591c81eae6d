"""The real ros_ai_bridge node between a real rclpy graph and independent WebSocket clients."""

from __future__ import annotations

import os
import queue
import re
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from byc_testing import INSTALL_LIB, running_process, wait_for
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from std_msgs.msg import String

from by_your_command.nodes import _qos

pytestmark = [pytest.mark.ros, pytest.mark.timeout(90)]

PROBE = str(Path(__file__).with_name("bridge_probe.py"))
TOKEN = "test-token-1f2e3d"


class Lines:
    """Collects a process's output lines on a thread, so tests can wait on them."""

    def __init__(self, process: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        self._queue: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._pump, args=(process,), daemon=True).start()

    def _pump(self, process: subprocess.Popen[str]) -> None:
        assert process.stdout is not None
        for line in process.stdout:
            self.lines.append(line.rstrip("\n"))

    def find(self, pattern: str) -> re.Match[str] | None:
        return next((m for line in list(self.lines) if (m := re.search(pattern, line))), None)


@contextmanager
def bridge_node(namespace: str, env: dict[str, str] | None = None) -> Iterator[tuple[int, Lines]]:
    args = [
        str(INSTALL_LIB / "ros_ai_bridge"),
        "--ros-args",
        "-r",
        f"__ns:={namespace}",
        "-p",
        "port:=0",
        "-p",
        "diagnostics_period_s:=0.2",
    ]
    with running_process(args, env=env) as process:
        lines = Lines(process)
        match = wait_for(
            lambda: lines.find(r"listening on 127\.0\.0\.1:(\d+)") or process.poll() is not None,
            timeout=20,
            what="bridge startup",
        )
        assert isinstance(match, re.Match), "\n".join(lines.lines)
        yield int(match.group(1)), lines


@pytest.mark.parametrize("library", ["roslibpy", "ours"])
def test_client_subscribes_and_publishes_through_the_bridge(
    library: str, ros_namespace: str, graph_node: Node
) -> None:
    node = graph_node
    responses: list[str] = []
    node.create_subscription(String, "response_text", lambda m: responses.append(m.data), _qos.RELIABLE)
    prompts = node.create_publisher(String, "prompt_text", _qos.RELIABLE)
    with bridge_node(ros_namespace, env={"BYC_BRIDGE_TOKEN": TOKEN}) as (port, bridge_lines):
        wait_for(
            lambda: prompts.get_subscription_count() >= 1, timeout=20, what="bridge subscribes prompt_text"
        )
        wait_for(
            lambda: node.count_publishers(f"{ros_namespace}/response_text") >= 1,
            timeout=20,
            what="bridge publishes response_text",
        )
        with running_process([sys.executable, PROBE, library, str(port), TOKEN]) as probe:
            probe_lines = Lines(probe)
            wait_for(lambda: probe_lines.find("^ready") or probe.poll() is not None, timeout=20, what="probe")

            def delivered() -> bool:
                prompts.publish(String(data="hello agent"))  # until the client's subscription is live
                return probe_lines.find(r"^RECV") is not None or probe.poll() is not None

            wait_for(delivered, timeout=20, interval=0.05, what="prompt_text reaches the client")
            assert probe_lines.find(r'^RECV \{"data": "hello agent"\}'), "\n".join(probe_lines.lines)
            wait_for(lambda: responses, timeout=20, what="response_text reaches ROS")
            assert responses[0] == f"{library} says hi"
        assert not any(TOKEN in line for line in bridge_lines.lines), "the token must never be logged"


def test_unauthorized_client_refused_and_diagnostics_published(ros_namespace: str, graph_node: Node) -> None:
    node = graph_node
    reports: list[DiagnosticArray] = []
    node.create_subscription(DiagnosticArray, "/diagnostics", reports.append, _qos.RELIABLE)
    with bridge_node(ros_namespace, env={"BYC_BRIDGE_TOKEN": TOKEN}) as (port, _):
        result = subprocess.run(
            [sys.executable, PROBE, "ours", str(port), "wrong-token"],
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert result.returncode != 0 and "401" in result.stderr

        def ours() -> dict[str, str] | None:
            for array in list(reports):
                for status in array.status:
                    if status.name.startswith(ros_namespace):
                        values = {kv.key: kv.value for kv in status.values}
                        if values.get("refused_connections") == "1":
                            return values
            return None

        values = wait_for(ours, timeout=20, what="diagnostics counting the refusal")
        assert values["clients"] == "0"


def test_binding_all_interfaces_without_a_token_is_a_startup_error(ros_namespace: str) -> None:
    args = [
        str(INSTALL_LIB / "ros_ai_bridge"),
        "--ros-args",
        "-r",
        f"__ns:={ros_namespace}",
        "-p",
        "host:=0.0.0.0",
        "-p",
        "port:=0",
    ]
    env = {key: value for key, value in os.environ.items() if key != "BYC_BRIDGE_TOKEN"}
    result = subprocess.run(args, capture_output=True, text=True, timeout=30, env=env)
    assert result.returncode != 0
    assert "without a token" in result.stdout + result.stderr
