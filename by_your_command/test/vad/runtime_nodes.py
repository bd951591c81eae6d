"""Small nodes that exercise nodes/_runtime.run_node in a process of their own (test_shutdown.py).

python runtime_nodes.py crash|stuck --ros-args -r __ns:=/ns
"""

from __future__ import annotations

import sys
import threading

from rclpy.node import Node
from std_msgs.msg import String

from by_your_command.nodes._qos import LATCHED
from by_your_command.nodes._runtime import run_node


class CrashingNode(Node):
    """A timer callback raises: the process must log it and exit non-zero, not hang."""

    def __init__(self) -> None:
        super().__init__("crashing_node")
        self.create_timer(0.05, self._tick)

    def _tick(self) -> None:
        raise RuntimeError("callback failed on purpose")


class StuckNode(Node):
    """Its before_shutdown never returns (after saying it started): only a second signal ends it."""

    def __init__(self) -> None:
        super().__init__("stuck_node")
        self.state = self.create_publisher(String, "runtime_state", LATCHED)
        self.state.publish(String(data="running"))

    def before_shutdown(self) -> None:
        self.state.publish(String(data="stopping"))
        threading.Event().wait()


if __name__ == "__main__":
    kind = sys.argv[1]
    run_node({"crash": CrashingNode, "stuck": StuckNode}[kind], sys.argv[2:])
