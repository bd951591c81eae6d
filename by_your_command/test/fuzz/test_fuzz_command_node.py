"""Prompt-injected command text through the real command_processor node on a real DDS graph.

The node runs with an allow-list of `stop` and `lookup`; every injection is published on
response_cmd. Nothing but `stop` and `lookup` may come out on arm_preset / behavior_command, and
the node's verdicts are exactly the pure processor's for the same text.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
import rclpy
from by_your_command_msgs.msg import CommandVerdict
from byc_testing import python_module, running_process, wait_for
from fuzzing import TALLY
from injection import INJECTIONS
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from std_msgs.msg import String

from by_your_command.commands.processor import CommandProcessor
from by_your_command.commands.safety import SafetyConfig, allow_list
from by_your_command.commands.vocabulary import load_vocabulary

pytestmark = [pytest.mark.ros, pytest.mark.timeout(180)]

RELIABLE = QoSProfile(depth=1000, reliability=QoSReliabilityPolicy.RELIABLE)
ALLOWED = ["stop", "lookup"]
SENTINEL = "end of the injections"


@pytest.fixture
def probe_node(ros_namespace: str) -> Iterator[tuple[Node, SingleThreadedExecutor]]:
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("injection_probe", namespace=ros_namespace, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        yield node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_injected_text_through_the_real_node_routes_only_allow_listed_commands(
    probe_node: tuple[Node, SingleThreadedExecutor], ros_namespace: str
) -> None:
    node, executor = probe_node
    received: dict[str, list[Any]] = {"arm_preset": [], "behavior_command": [], "command_status": []}
    subscriptions = [
        node.create_subscription(String, "arm_preset", received["arm_preset"].append, RELIABLE),
        node.create_subscription(String, "behavior_command", received["behavior_command"].append, RELIABLE),
        node.create_subscription(
            CommandVerdict, "command_status", received["command_status"].append, RELIABLE
        ),
    ]
    publisher = node.create_publisher(String, "response_cmd", RELIABLE)
    args = [
        *python_module("by_your_command.nodes.command_processor"),
        "--ros-args",
        "-r",
        f"__ns:={ros_namespace}",
        "-p",
        f"allowed_commands:=[{', '.join(ALLOWED)}]",
        "-p",
        "min_interval_s:=0.0",
    ]
    with running_process(args) as process:

        def connected() -> bool:
            assert process.poll() is None, process.stdout.read() if process.stdout else "died"
            executor.spin_once(timeout_sec=0.02)
            return publisher.get_subscription_count() > 0 and all(
                s.get_publisher_count() > 0 for s in subscriptions
            )

        wait_for(connected, timeout=60, what="command_processor discovered")
        # Our side matching says nothing of the node's: a verdict it publishes before its writer
        # matched our reader is lost. A warm-up line answered proves the way back.
        tries = iter(range(1, 10_000))

        def warmed_up() -> bool:
            marker = f"warm-up {next(tries)}"
            publisher.publish(String(data=marker))
            for _ in range(25):
                executor.spin_once(timeout_sec=0.02)
                if any(v.raw == marker for v in received["command_status"]):
                    return True
            return False

        wait_for(warmed_up, timeout=60, what="a verdict back from command_processor")
        for messages in received.values():
            messages.clear()
        with TALLY.input("command_processor node (injections)", count=len(INJECTIONS)):
            for text in [*INJECTIONS, SENTINEL]:
                publisher.publish(String(data=text))

            def sentinel_answered() -> bool:
                executor.spin_once(timeout_sec=0.02)
                return any(v.raw == SENTINEL for v in received["command_status"])

            wait_for(sentinel_answered, timeout=90, what="a verdict for the last message")

    routed = [m.data for m in received["arm_preset"] + received["behavior_command"]]
    assert routed and all(command.partition("@")[0] in ALLOWED for command in routed), routed
    pure = CommandProcessor(load_vocabulary(), SafetyConfig(allow_list(ALLOWED), 0.0))
    # A ROS string ends at its first NUL (rosidl strings are C strings): the node sees only that part.
    sent = [text.partition("\x00")[0] for text in INJECTIONS]
    expected = [(v.raw, v.command, v.accepted) for text in sent for v in pure.process(text, 0.0)]
    got = [(v.raw, v.command, v.accepted) for v in received["command_status"] if v.raw != SENTINEL]
    assert got == expected
