"""Start, spin and stop a node the same way everywhere (ros2 run, byc, tests)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.node import Node


def run_node(make_node: Callable[[], Node], args: Sequence[str] | None = None, threads: int = 1) -> None:
    """Create the node, spin until SIGINT/SIGTERM, then tear everything down.

    rclpy's own handlers (installed by init for SIGINT and SIGTERM) shut the context down and
    wake the executor at once, so `terminate()` ends the process promptly and the node is still
    destroyed cleanly (files flushed, devices closed). A Python-level handler would only run
    when the executor's wait returned, which can be seconds.
    """
    rclpy.init(args=list(args) if args is not None else None)
    node = None
    try:
        node = make_node()
        executor = SingleThreadedExecutor() if threads <= 1 else MultiThreadedExecutor(num_threads=threads)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
