"""A small in-test rclpy node (own context) to publish to and listen on the nodes under test."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node


class Probe:
    def __init__(self, node: Node, executor: SingleThreadedExecutor) -> None:
        self.node = node
        self.executor = executor
        self.received: dict[str, list[Any]] = {}

    def listen(self, msg_type: Any, topic: str, qos: Any) -> list[Any]:
        store = self.received.setdefault(topic, [])
        self.node.create_subscription(msg_type, topic, store.append, qos)
        return store

    def spin(self, timeout_sec: float = 0.01) -> None:
        self.executor.spin_once(timeout_sec=timeout_sec)

    def topic(self, name: str) -> str:
        return f"{self.node.get_namespace()}/{name}"


@contextmanager
def probe_node(namespace: str, name: str = "probe") -> Iterator[Probe]:
    context = Context()
    rclpy.init(context=context)
    node = Node(name, namespace=namespace, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield Probe(node, executor)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


@contextmanager
def spinning_node(namespace: str, name: str = "probe") -> Iterator[Node]:
    """A probe node spun on a background thread, for tests that only publish and listen."""
    with probe_node(namespace, name) as probe:
        thread = threading.Thread(target=probe.executor.spin, daemon=True)
        thread.start()
        try:
            yield probe.node
        finally:
            probe.executor.shutdown()
            thread.join(timeout=5)
