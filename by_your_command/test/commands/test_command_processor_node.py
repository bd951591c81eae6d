"""command_processor in a real rclpy graph: response_cmd in; arm, behavior, wake and verdicts out."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
import rclpy
from by_your_command_msgs.msg import CommandRequest, CommandVerdict
from byc_testing import REPO_ROOT, python_module, running_process, wait_for
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from std_msgs.msg import Bool, String

from by_your_command.commands.processor import SUPERSEDED

RELIABLE = QoSProfile(depth=100, reliability=QoSReliabilityPolicy.RELIABLE)
GRUNT1_CONFIG = REPO_ROOT / "by_your_command" / "config" / "command_processor_grunt1.yaml"


@dataclass
class Probe:
    """The test's side of the graph: publishes response_cmd, records every output topic."""

    node: Node
    executor: SingleThreadedExecutor
    publisher: Any
    received: dict[str, list[Any]] = field(default_factory=dict)

    def spin(self) -> None:
        self.executor.spin_once(timeout_sec=0.02)

    def send(self, text: str) -> None:
        self.publisher.publish(String(data=text))

    def data(self, topic: str) -> list[Any]:
        return [getattr(message, "data", message) for message in self.received.get(topic, [])]

    def verdicts(self) -> list[CommandVerdict]:
        return self.received.get("command_status", [])


@pytest.fixture
def probe(ros_namespace: str) -> Iterator[Probe]:
    rclpy.init()
    node = Node("command_processor_probe", namespace=ros_namespace)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    probe = Probe(node, executor, node.create_publisher(String, "response_cmd", RELIABLE))
    try:
        yield probe
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def listen(probe: Probe, topic: str, message_type: type, key: str | None = None) -> Any:
    def store(message: Any) -> None:
        probe.received.setdefault(key or topic, []).append(message)

    return probe.node.create_subscription(message_type, topic, store, RELIABLE)


def start_processor(namespace: str, *ros_args: str) -> Any:
    module = python_module("by_your_command.nodes.command_processor")
    return running_process([*module, "--ros-args", "-r", f"__ns:={namespace}", *ros_args])


def wait_connected(probe: Probe, process: Any, subscriptions: list[Any]) -> None:
    def ready() -> bool:
        assert process.poll() is None, f"command_processor died: {process.stdout.read()}"
        probe.spin()
        return probe.publisher.get_subscription_count() > 0 and all(
            sub.get_publisher_count() > 0 for sub in subscriptions
        )

    wait_for(ready, timeout=20, what="command_processor discovered")
    # Our side matching says nothing of the processor's: its verdicts (and commands) published
    # before its writers matched our readers would be lost. A chat line's verdict coming back
    # proves the way back; the verdicts of earlier tries come before it (one ordered writer).
    verdict_topic = probe.node.get_namespace().rstrip("/") + "/command_status"
    if not any(sub.topic_name == verdict_topic for sub in subscriptions):
        return
    tries = iter(range(1, 1000))

    def answered() -> bool:
        marker = f"warm-up {next(tries)}"
        probe.send(marker)
        for _ in range(25):
            probe.spin()
            if any(v.raw == marker for v in probe.verdicts()):
                return True
        return False

    wait_for(answered, timeout=20, what="a verdict back from command_processor")
    probe.received.clear()


@pytest.mark.ros
def test_commands_are_routed_and_every_verdict_is_published(probe: Probe, ros_namespace: str) -> None:
    subscriptions = [
        listen(probe, "arm_preset", String),
        listen(probe, "behavior_command", String),
        listen(probe, "wake_cmd", Bool),
        listen(probe, "command_status", CommandVerdict),
    ]
    with start_processor(ros_namespace, "-p", "min_interval_s:=0.0") as process:
        wait_connected(probe, process, subscriptions)
        probe.send("```\nCOMMAND: Pan left.\nfollow@person\n```")
        probe.send("good morning!")
        probe.send("sleep; wake; tenhut")

        def all_verdicts() -> bool:
            probe.spin()
            return len(probe.verdicts()) >= 6

        wait_for(all_verdicts, timeout=30, what="6 verdicts")
        wait_for(lambda: probe.spin() or len(probe.data("wake_cmd")) >= 2, timeout=30, what="wake_cmd")

    assert probe.data("arm_preset") == ["pan@left", "tenhut"]
    assert probe.data("behavior_command") == ["follow@person", "sleep", "wake"]
    assert probe.data("wake_cmd") == [False, True]
    summary = [(v.raw, v.command, v.accepted, v.topic) for v in probe.verdicts()]
    assert summary == [
        ("COMMAND: Pan left", "pan@left", True, f"{ros_namespace}/arm_preset"),
        ("follow@person", "follow@person", True, f"{ros_namespace}/behavior_command"),
        ("good morning!", "", False, ""),
        ("sleep", "sleep", True, f"{ros_namespace}/behavior_command"),
        ("wake", "wake", True, f"{ros_namespace}/behavior_command"),
        ("tenhut", "tenhut", True, f"{ros_namespace}/arm_preset"),
    ]
    assert "unknown command" in probe.verdicts()[2].reason
    assert {(v.request_id, v.count) for v in probe.verdicts()} == {("", 2), ("", 1), ("", 3)}


@pytest.mark.ros
def test_a_request_s_verdicts_carry_its_id_and_their_place(probe: Probe, ros_namespace: str) -> None:
    """A tool call's verdicts are told apart by identity: the same text on response_cmd (another
    source) gets verdicts without the id, and a request with no command still gets its answer."""
    requests = probe.node.create_publisher(CommandRequest, "command_request", RELIABLE)
    subscriptions = [listen(probe, "command_status", CommandVerdict), listen(probe, "arm_preset", String)]
    with start_processor(ros_namespace, "-p", "min_interval_s:=0.0") as process:
        wait_connected(probe, process, subscriptions)
        wait_for(lambda: probe.spin() or requests.get_subscription_count() > 0, timeout=20, what="requests")
        probe.send("lookup, pan@left")
        requests.publish(CommandRequest(request_id="agent-a-1", text="lookup, pan@left"))
        requests.publish(CommandRequest(request_id="agent-a-2", text=" , "))
        wait_for(lambda: probe.spin() or len(probe.verdicts()) >= 5, timeout=30, what="5 verdicts")

    # the two topics are two queues: their messages may be handled in either order
    places = sorted((v.request_id, v.index, v.count, v.command, v.accepted) for v in probe.verdicts())
    assert places == [
        ("", 0, 2, "lookup", True),
        ("", 1, 2, "pan@left", True),
        ("agent-a-1", 0, 2, "lookup", True),
        ("agent-a-1", 1, 2, "pan@left", True),
        ("agent-a-2", 0, 1, "", False),
    ]
    [empty] = [v for v in probe.verdicts() if v.request_id == "agent-a-2"]
    assert "no command" in empty.reason
    assert sorted(probe.data("arm_preset")) == ["lookup", "lookup", "pan@left", "pan@left"]


@pytest.mark.ros
def test_safety_layer_in_the_graph(probe: Probe, ros_namespace: str) -> None:
    subscriptions = [
        listen(probe, "behavior_command", String),
        listen(probe, "command_status", CommandVerdict),
    ]
    args = ("-p", "allowed_commands:=[lookup]", "-p", "min_interval_s:=60.0")
    with start_processor(ros_namespace, *args) as process:
        wait_connected(probe, process, subscriptions)
        probe.send("stop, stop, lookup, lookup, reach")

        def five_verdicts() -> bool:
            probe.spin()
            return len(probe.verdicts()) >= 5

        wait_for(five_verdicts, timeout=30, what="5 verdicts")
    assert [(v.command, v.accepted) for v in probe.verdicts()] == [
        ("stop", True),
        ("stop", True),
        ("lookup", True),
        ("lookup", False),
        ("reach", False),
    ]
    assert "rate limited" in probe.verdicts()[3].reason
    assert "allow-list" in probe.verdicts()[4].reason


@pytest.mark.ros
def test_grunt1_example_config_publishes_on_absolute_robot_topics(probe: Probe, ros_namespace: str) -> None:
    # The seed's wiring: namespaced input, absolute /grunt1/... outputs (isolated per test run by domain).
    subscriptions = [
        listen(probe, "/grunt1/arm_preset", String, "arm"),
        listen(probe, "/grunt1/behavior_command", String, "behavior"),
        listen(probe, "command_status", CommandVerdict),
    ]
    with start_processor(ros_namespace, "--params-file", str(GRUNT1_CONFIG)) as process:
        wait_connected(probe, process, subscriptions)
        probe.send("lookout\ntrack@cup")

        def routed() -> bool:
            probe.spin()
            return bool(probe.data("arm")) and bool(probe.data("behavior"))

        wait_for(routed, timeout=30, what="/grunt1 outputs")
    assert probe.data("arm") == ["lookout"]
    assert probe.data("behavior") == ["track@cup"]


def wait_verdicts(probe: Probe, process: Any, count: int) -> list[CommandVerdict]:
    def arrived() -> bool:
        assert process.poll() is None, "command_processor died"
        probe.spin()
        return len(probe.verdicts()) >= count

    wait_for(arrived, timeout=30, what=f"{count} verdicts")
    return probe.verdicts()


@pytest.mark.ros
def test_oversize_junk_gets_one_verdict_each_and_a_following_stop_is_answered(
    probe: Probe, ros_namespace: str
) -> None:
    subscriptions = [
        listen(probe, "behavior_command", String),
        listen(probe, "arm_preset", String),
        listen(probe, "command_status", CommandVerdict),
    ]
    junk = ["lookup, " * 131_072, "a," * 500_000, "command:" * 125_000]  # about 1 MB each
    with start_processor(ros_namespace) as process:
        wait_connected(probe, process, subscriptions)
        for message in junk:
            probe.send(message)
        probe.send("stop")
        verdicts = wait_verdicts(probe, process, len(junk) + 1)
        wait_for(lambda: probe.spin() or probe.data("behavior_command"), timeout=30, what="stop routed")
    for verdict, message in zip(verdicts[: len(junk)], junk, strict=True):
        assert not verdict.accepted and verdict.topic == ""
        assert verdict.reason == f"message of {len(message)} characters is longer than 4096: not examined"
        assert len(verdict.raw) <= 201  # the megabyte is not echoed back
    assert [(v.command, v.accepted) for v in verdicts[len(junk) :]] == [("stop", True)]
    assert probe.data("behavior_command") == ["stop"] and probe.data("arm_preset") == []


@pytest.mark.ros
def test_a_stop_inside_a_long_message_is_routed_first(probe: Probe, ros_namespace: str) -> None:
    subscriptions = [
        listen(probe, "behavior_command", String),
        listen(probe, "arm_preset", String),
        listen(probe, "command_status", CommandVerdict),
    ]
    chatter = ", ".join(f"now I will think about item {index}" for index in range(40))
    long_message = f"reach, {chatter}, stop, lookup"  # the stop is beyond the 20 pieces parsed
    huge_message = "lookup\n" + "x " * 400_000 + "\nSTOP!\n" + "y " * 100_000  # oversize, stop inside
    with start_processor(ros_namespace, "-p", "min_interval_s:=0.0") as process:
        wait_connected(probe, process, subscriptions)
        probe.send(long_message)
        probe.send(huge_message)
        probe.send("pan@left, stop, tenhut")
        verdicts = wait_verdicts(probe, process, 22 + 2 + 3)
        wait_for(lambda: probe.spin() or len(probe.data("behavior_command")) >= 3, timeout=30, what="stops")
    first, second, third = verdicts[:22], verdicts[22:24], verdicts[24:]
    assert (first[0].command, first[0].accepted) == ("stop", True)  # before anything else
    assert (first[1].command, first[1].accepted, first[1].reason) == ("reach", False, SUPERSEDED)
    assert not any(v.accepted for v in first[1:]) and "not examined" in first[-1].reason
    assert [(v.command, v.accepted) for v in second] == [("stop", True), ("", False)]
    assert "not examined" in second[1].reason
    assert [(v.command, v.accepted) for v in third] == [("stop", True), ("pan@left", False), ("tenhut", True)]
    assert probe.data("behavior_command") == ["stop", "stop", "stop"]
    assert probe.data("arm_preset") == ["tenhut"]  # nothing the stops superseded ever moved the arm


@pytest.mark.ros
def test_an_internal_error_is_logged_and_counted_and_the_node_keeps_listening(probe: Probe) -> None:
    from by_your_command.nodes.command_processor import CommandProcessorNode

    node = CommandProcessorNode()  # in this process, in the probe's context, called directly
    try:
        healthy = node.processor.process

        def broken(message: str, now: float) -> list[Any]:
            raise RuntimeError("a bug in the processor")

        node.processor.process = broken  # type: ignore[method-assign]
        subscription = next(s for s in node.subscriptions if s.topic_name.endswith("/response_cmd"))
        subscription.callback(String(data="stop"))  # unguarded, this would end the executor's spin
        assert node.internal_errors == 1
        node.processor.process = healthy  # type: ignore[method-assign]
        subscription.callback(String(data="stop"))
        assert (node.accepted, node.refused) == (1, 0)
    finally:
        node.destroy_node()
