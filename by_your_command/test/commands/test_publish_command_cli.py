"""publish_command: the manual-test CLI publishes through rclpy and prints the processor's verdicts."""

from __future__ import annotations

import subprocess

import pytest
from byc_testing import python_module, running_process


def start_processor(namespace: str) -> object:
    module = python_module("by_your_command.nodes.command_processor")
    return running_process([*module, "--ros-args", "-r", f"__ns:={namespace}"])


@pytest.mark.ros
def test_publish_command_cli_shows_verdicts(ros_namespace: str) -> None:
    with start_processor(ros_namespace) as process:
        cli = python_module(
            "by_your_command.cli.publish_command", "--namespace", ros_namespace, "pan@left, hello"
        )
        result = subprocess.run(cli, capture_output=True, text=True, timeout=60)
        fire_and_forget = subprocess.run([*cli, "--no-wait"], capture_output=True, text=True, timeout=60)
        assert process.poll() is None
    assert fire_and_forget.returncode == 0 and fire_and_forget.stdout == "", fire_and_forget.stderr
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith("accepted  'pan@left'  pan@left -> ") and lines[0].endswith("(arm command)")
    assert lines[1].startswith("REFUSED   'hello'")


@pytest.mark.ros
def test_publish_command_cli_fails_clearly_without_a_processor(ros_namespace: str) -> None:
    cli = python_module(
        "by_your_command.cli.publish_command", "--namespace", ros_namespace, "--timeout", "1", "stop"
    )
    result = subprocess.run(cli, capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert "nobody subscribes" in result.stderr
