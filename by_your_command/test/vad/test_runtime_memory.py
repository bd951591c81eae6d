"""Memory of a node run by nodes/_runtime.run_node stays flat however many callbacks it runs.

The soak found every audio node growing by ~240 bytes per message (110 MB an hour at 4x): rclpy's
executor added a wake-up callback to run_node's stop future on every callback it ran and kept
them all (fixed by _runtime._StopFuture). The figure per audio node: bench/bench_memory.py."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from byc_testing import running_process, wait_for

RUNTIME_NODES = Path(__file__).with_name("runtime_nodes.py")
# The leak was ~250 bytes per callback; what is left is noise (an int here, a cache entry there).
MAX_GROWTH_PER_CALLBACK = 64


def exited(process: subprocess.Popen[str]) -> bool:
    return process.poll() is not None


@pytest.mark.ros
def test_the_python_heap_does_not_grow_with_the_callbacks_run(ros_namespace: str) -> None:
    command = [sys.executable, str(RUNTIME_NODES), "busy", "--ros-args", "-r", f"__ns:={ros_namespace}"]
    with running_process(command) as busy:
        wait_for(lambda: exited(busy), timeout=60, what="the busy node to measure and stop itself")
        text = busy.stdout.read() if busy.stdout else ""
    assert busy.returncode == 0, text
    found = re.search(r"heap growth (-?\d+) bytes over (\d+) callbacks \((\d+) received\)", text)
    assert found, text
    growth, callbacks, received = (int(value) for value in found.groups())
    assert received > 0, "the node's audio never reached its own subscription: the test measured timers only"
    assert growth / callbacks < MAX_GROWTH_PER_CALLBACK, f"{growth} bytes over {callbacks} callbacks"
