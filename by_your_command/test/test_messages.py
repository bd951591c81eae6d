"""Our messages import, carry what they claim, and survive a trip through DDS and back."""

from __future__ import annotations

import array
import sys
from pathlib import Path

import pytest
import rclpy
from by_your_command_msgs.msg import (
    AudioChunk,
    AudioDataUtterance,
    AudioDataUtteranceStamped,
    CommandRequest,
    CommandVerdict,
    PlaybackStatus,
)
from byc_testing import running_process, wait_for
from rclpy.node import Node
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message


def sample_messages() -> dict[str, object]:
    chunk = AudioChunk(sample_rate=24000, channels=1, stream_id="response-7")
    chunk.header.stamp.sec = 12
    chunk.header.frame_id = "mic"
    chunk.data = array.array("h", [0, 1, -1, 32767, -32768])

    utterance = AudioDataUtterance(
        utterance_id=1_700_000_000_123_456_789,
        is_utterance_end=True,
        chunk_sequence=3,
        sample_rate=16000,
        channels=1,
    )
    utterance.int16_data = array.array("h", range(-256, 256))

    stamped = AudioDataUtteranceStamped(audio_data_utterance=utterance)
    stamped.header.stamp.nanosec = 5

    status = PlaybackStatus(
        stream_id="response-7", played_ms=1234, queued_ms=40, speaking=True, finished=False, interrupted=False
    )
    verdict = CommandVerdict(
        raw="Pan left.",
        command="pan@left",
        accepted=True,
        reason="arm preset",
        topic="arm_preset",
        request_id="agent-1f2e3d-7",
        index=1,
        count=2,
    )
    request = CommandRequest(request_id="agent-1f2e3d-7", text="lookup, pan@left")
    return {
        "by_your_command_msgs/msg/AudioChunk": chunk,
        "by_your_command_msgs/msg/AudioDataUtterance": utterance,
        "by_your_command_msgs/msg/AudioDataUtteranceStamped": stamped,
        "by_your_command_msgs/msg/PlaybackStatus": status,
        "by_your_command_msgs/msg/CommandVerdict": verdict,
        "by_your_command_msgs/msg/CommandRequest": request,
    }


@pytest.mark.unit
@pytest.mark.parametrize("type_name", sorted(sample_messages()))
def test_serialization_round_trip(type_name: str) -> None:
    message = sample_messages()[type_name]
    restored = deserialize_message(serialize_message(message), type(message))
    assert restored == message


@pytest.mark.unit
def test_audio_messages_carry_rate_and_channels() -> None:
    for cls in (AudioChunk, AudioDataUtterance):
        fields = cls.get_fields_and_field_types()
        assert fields["sample_rate"] == "uint32"
        assert fields["channels"] == "uint8"
    utterance_fields = AudioDataUtterance.get_fields_and_field_types()
    for seed_field in ("int16_data", "utterance_id", "is_utterance_end", "chunk_sequence"):
        assert seed_field in utterance_fields


@pytest.mark.ros
def test_round_trip_through_a_second_process(ros_namespace: str) -> None:
    """Publish each message to a separate rclpy process and get the same message back."""
    messages = sample_messages()
    echo_script = str(Path(__file__).with_name("ros_echo.py"))
    rclpy.init()
    node = Node("round_trip_test", namespace=ros_namespace)
    received: dict[str, object] = {}
    qos = QoSProfile(depth=10, reliability=QoSReliabilityPolicy.RELIABLE)
    publishers = {}
    for type_name, message in messages.items():
        short = type_name.split("/")[-1]
        publishers[type_name] = node.create_publisher(type(message), f"in_{short}", qos)

        def store(msg: object, key: str = type_name) -> None:
            received.setdefault(key, msg)

        node.create_subscription(type(message), f"out_{short}", store, qos)
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)
    try:
        with running_process([sys.executable, echo_script, ros_namespace, *messages]) as echo:

            def all_echoed() -> bool:
                assert echo.poll() is None, f"echo process died: {echo.stdout.read() if echo.stdout else ''}"
                for type_name, publisher in publishers.items():
                    if type_name not in received and publisher.get_subscription_count() > 0:
                        publisher.publish(messages[type_name])
                executor.spin_once(timeout_sec=0.05)
                return len(received) == len(messages)

            wait_for(all_echoed, timeout=30, what="every message type echoed by the second process")
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    for type_name, message in messages.items():
        assert received[type_name] == message, type_name
