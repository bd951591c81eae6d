"""Bridge tests: helpers (harnesses, fake ROS port) from this directory, and a spinning graph node."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from rclpy.node import Node
from ros_probe import spinning_node

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)


@pytest.fixture
def graph_node(ros_namespace: str) -> Iterator[Node]:
    """A node in its own context, spun in a background thread, for tests to publish and listen."""
    with spinning_node(ros_namespace, "bridge_test") as node:
        yield node
