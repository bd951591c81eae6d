"""audio_capture on this machine (no sound card): a clear failure naming what it looked for."""

from __future__ import annotations

import subprocess

import pytest
from byc_testing import python_module

from by_your_command.audio.devices import query_devices


@pytest.mark.ros
def test_capture_without_a_matching_device_fails_clearly(ros_namespace: str) -> None:
    command = python_module(
        "by_your_command.nodes.audio_capture",
        "--ros-args", "-r", f"__ns:={ros_namespace}", "-p", "device:=no-such-microphone-xyz",
    )  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert result.returncode != 0
    assert "no-such-microphone-xyz" in result.stderr and "input device" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.unit
def test_list_devices_flag_prints_the_table_and_exits() -> None:
    result = subprocess.run(
        python_module("by_your_command.nodes.audio_capture", "--list-devices"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0
    devices, _, _ = query_devices()
    assert ("idx" in result.stdout) if devices else ("no audio devices" in result.stdout)
