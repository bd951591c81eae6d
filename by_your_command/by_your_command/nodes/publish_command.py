"""The rclpy half of the publish_command CLI: publish texts on response_cmd, collect verdicts."""

from __future__ import annotations

import time

import rclpy
from by_your_command_msgs.msg import CommandVerdict
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from std_msgs.msg import String

from by_your_command.nodes._qos import RELIABLE

QUIET_S = 0.5  # after the last verdict, how long to wait for more before returning


class NoSubscriber(RuntimeError):
    pass


def publish_commands(
    texts: list[str],
    topic: str = "response_cmd",
    status_topic: str = "command_status",
    namespace: str = "",
    wait_for_verdicts: bool = True,
    timeout: float = 5.0,
) -> list[CommandVerdict]:
    """Publish each text as one String message; return the verdicts seen on `status_topic`."""
    rclpy.init()
    node = Node("publish_command", namespace=namespace or None)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    verdicts: list[CommandVerdict] = []
    try:
        publisher = node.create_publisher(String, topic, RELIABLE)
        status = node.create_subscription(CommandVerdict, status_topic, verdicts.append, RELIABLE)
        deadline = time.monotonic() + timeout
        while publisher.get_subscription_count() == 0 or (
            wait_for_verdicts and status.get_publisher_count() == 0
        ):
            if time.monotonic() > deadline:
                raise NoSubscriber(
                    f"nobody subscribes to {publisher.topic_name} (is command_processor running?)"
                )
            executor.spin_once(timeout_sec=0.05)
        for text in texts:
            publisher.publish(String(data=text))
        if wait_for_verdicts:
            last_count, last_change = 0, time.monotonic()
            while time.monotonic() < deadline:
                executor.spin_once(timeout_sec=0.05)
                if len(verdicts) != last_count:
                    last_count, last_change = len(verdicts), time.monotonic()
                elif len(verdicts) >= len(texts) and time.monotonic() - last_change > QUIET_S:
                    break
        else:
            # Reliable delivery needs the publisher alive until the subscriber has the data.
            publisher.wait_for_all_acked(Duration(seconds=timeout))
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return verdicts
