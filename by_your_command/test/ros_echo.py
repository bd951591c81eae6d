"""A second process for round-trip tests: republishes every message type it is told about.

usage: python ros_echo.py NAMESPACE pkg/msg/Type [pkg/msg/Type ...]
Each type T is echoed from NAMESPACE/in_<T> to NAMESPACE/out_<T>.
"""

from __future__ import annotations

import importlib
import sys

import rclpy
from rclpy.node import Node
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy


def message_class(type_name: str) -> type:
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)  # type: ignore[no-any-return]


def main() -> None:
    namespace, type_names = sys.argv[1], sys.argv[2:]
    rclpy.init()
    node = Node("ros_echo", namespace=namespace)
    qos = QoSProfile(
        depth=10, reliability=QoSReliabilityPolicy.RELIABLE, durability=QoSDurabilityPolicy.VOLATILE
    )
    for type_name in type_names:
        cls = message_class(type_name)
        short = type_name.split("/")[-1]
        publisher = node.create_publisher(cls, f"out_{short}", qos)
        node.create_subscription(cls, f"in_{short}", publisher.publish, qos)
    print("ready", flush=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
