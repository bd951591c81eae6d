"""Bridge tests: helpers (harnesses, fake ROS port) from this directory, and a spinning graph node."""

from __future__ import annotations

import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)


@pytest.fixture
def graph_node(ros_namespace: str) -> Iterator[Node]:
    """A node in its own context, spun in a background thread, for tests to publish and listen."""
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("bridge_test", namespace=ros_namespace, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield node
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        thread.join(timeout=5)
