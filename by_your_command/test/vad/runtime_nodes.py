"""Small nodes that exercise nodes/_runtime.run_node in a process of their own (test_shutdown.py,
test_runtime_memory.py).

python runtime_nodes.py crash|stuck|busy --ros-args -r __ns:=/ns
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import tracemalloc

import numpy as np
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk
from rclpy.node import Node
from std_msgs.msg import String

from by_your_command.nodes._audio_msgs import make_audio_chunk, pcm_of
from by_your_command.nodes._qos import AUDIO_IN, LATCHED, STREAM
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


class BusyNode(Node):
    """Audio traffic through run_node, like an audio node's: a 1 ms timer publishes AudioChunks
    (make_audio_chunk, stamped) that its own subscription reads (pcm_of). The Python heap is traced
    from WARMUP callbacks on for MEASURED more; then the node prints the growth and stops
    itself with SIGTERM (run_node's graceful path)."""

    WARMUP = 500
    MEASURED = 2000

    def __init__(self) -> None:
        super().__init__("busy_node")
        self.pcm = np.arange(512, dtype=np.int16)
        self.publisher = self.create_publisher(AudioChunk, "runtime_audio", STREAM)
        self.create_subscription(AudioChunk, "runtime_audio", self._on_audio, AUDIO_IN)
        self.create_timer(0.001, self._tick)
        self.callbacks = 0
        self.received = 0
        self.heap_at_warmup = 0
        tracemalloc.start()

    def _tick(self) -> None:
        self.publisher.publish(make_audio_chunk(self.pcm, 16000, 1, Time(sec=1, nanosec=self.callbacks)))
        self._count()

    def _on_audio(self, msg: AudioChunk) -> None:
        self.received += int(pcm_of(msg)[-1] == 511)
        self._count()

    def _count(self) -> None:
        self.callbacks += 1
        if self.callbacks == self.WARMUP:
            self.heap_at_warmup = tracemalloc.get_traced_memory()[0]
        elif self.callbacks == self.WARMUP + self.MEASURED:
            growth = tracemalloc.get_traced_memory()[0] - self.heap_at_warmup
            print(f"heap growth {growth} bytes over {self.MEASURED} callbacks ({self.received} received)")
            sys.stdout.flush()
            os.kill(os.getpid(), signal.SIGTERM)


if __name__ == "__main__":
    kind = sys.argv[1]
    run_node({"crash": CrashingNode, "stuck": StuckNode, "busy": BusyNode}[kind], sys.argv[2:])
