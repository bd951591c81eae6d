"""A small in-test rclpy node that listens to and publishes into the graph under test."""

from __future__ import annotations

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

    def listen(self, msg_type: Any, topic: str, qos: Any) -> list[Any]:
        received: list[Any] = []
        self.node.create_subscription(msg_type, topic, received.append, qos)
        return received

    def spin(self, timeout_sec: float = 0.01) -> None:
        self.executor.spin_once(timeout_sec=timeout_sec)

    def topic(self, name: str) -> str:
        return f"{self.node.get_namespace()}/{name}"


@contextmanager
def probe_node(namespace: str) -> Iterator[Probe]:
    context = Context()
    rclpy.init(context=context)
    node = Node("vad_test_probe", namespace=namespace, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield Probe(node, executor)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
