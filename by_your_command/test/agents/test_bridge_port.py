"""The bridge adapter: rosbridge JSON → typed inputs (untrusted: invalid ones are reported as lost),
typed publishes → the message shapes of docs/topics.md."""

from __future__ import annotations

import asyncio
import base64
import json
from typing import Any

import pytest

from by_your_command.agents.bridge_port import BridgePort
from by_your_command.agents.config import AgentConfig, AgentRole, ContextSource, Topics
from by_your_command.agents.detections import Detection, FrameInfo
from by_your_command.agents.inputs import (
    Attention,
    AttentionChanged,
    CameraFrame,
    InputLost,
    PlaybackStatus,
    SafetyStop,
    SharedTurn,
    UtteranceChunk,
)
from by_your_command.agents.metrics import TurnMetrics
from by_your_command.agents.port import DetectionReport, PortClosed, PortUnavailable, VoiceChunk
from by_your_command.agents.provider import Role
from by_your_command.bridge.client_messages import BridgeUnavailable, ClientClosed, Delivery, Lost, Received

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


class FakeClient:
    def __init__(self, *deliveries: Delivery) -> None:
        self.deliveries = list(deliveries)
        self.subscribed: dict[str, str | None] = {}
        self.advertised: dict[str, str] = {}
        self.published: list[tuple[str, dict[str, Any]]] = []
        self.down = False

    async def subscribe(self, topic: str, msg_type: str | None = None) -> None:
        self.subscribed[topic] = msg_type

    async def advertise(self, topic: str, msg_type: str) -> None:
        self.advertised[topic] = msg_type

    async def publish(self, topic: str, msg: dict[str, Any]) -> None:
        if self.down:
            raise BridgeUnavailable("not connected")
        self.published.append((topic, msg))

    async def receive(self, timeout: float | None = None) -> Delivery:
        if not self.deliveries:
            raise ClientClosed("closed")
        return self.deliveries.pop(0)


def received(topic: str, msg: dict[str, Any]) -> Received:
    return Received(topic, "text", msg, 0.0)


def convert(msg: dict[str, Any], topic: str, config: AgentConfig | None = None) -> object:
    return BridgePort(FakeClient(), config or AgentConfig()).convert(received(topic, msg))


def test_inputs_convert_and_invalid_ones_are_reported_as_lost() -> None:
    chunk = convert(
        {
            "int16_data": [1, -2, 32767],
            "utterance_id": 9,
            "chunk_sequence": 2,
            "is_utterance_end": True,
            "sample_rate": 16000,
            "channels": 1,
        },
        "prompt_voice",
    )
    assert chunk == UtteranceChunk(b"\x01\x00\xfe\xff\xff\x7f", 16000, 9, 2, True)
    assert convert({"data": " Asleep "}, "attention_state") == AttentionChanged(Attention.ASLEEP)
    assert convert({"stream_id": "s", "played_ms": 5, "speaking": True}, "playback_status") == PlaybackStatus(
        "s", 5, 0, True
    )
    jpeg = base64.b64encode(b"\xff\xd8").decode()
    assert convert({"format": "jpeg", "data": jpeg}, "camera_forwarded") == CameraFrame(b"\xff\xd8")
    stop = {"phrase": "halt" * 100, "utterance_id": 2**63, "word_start": {"sec": 1, "nanosec": 0}}
    assert convert(stop, "safety_stop") == SafetyStop("halt" * 50, 2**63)  # bounded phrase
    for msg, topic in [
        ({"int16_data": [40000]}, "prompt_voice"),
        ({"int16_data": "AAA="}, "prompt_voice"),
        ({"int16_data": [1], "channels": 2}, "prompt_voice"),
        ({"data": "dreaming"}, "attention_state"),
        ({"data": 3}, "prompt_text"),
        ({"stream_id": "s", "played_ms": True}, "playback_status"),
        ({"format": "png", "data": jpeg}, "camera_forwarded"),
        ({"data": "x"}, "some_other_topic"),
        ({"data": "stop"}, "safety_stop"),  # the old String shape: no phrase
        ({"phrase": "stop", "utterance_id": -1}, "safety_stop"),
        ({"phrase": "stop", "utterance_id": 2**64}, "safety_stop"),
        ({"phrase": "stop", "utterance_id": "7"}, "safety_stop"),
    ]:
        lost = convert(msg, topic)
        assert isinstance(lost, InputLost) and lost.reason.startswith("invalid message"), (msg, lost)


def test_shared_transcript_is_read_only_by_a_shared_context_agent() -> None:
    shared = AgentConfig(role=AgentRole.COMMAND, context_source=ContextSource.SHARED)
    assert convert({"data": "hi"}, "prompt_transcript", shared) == SharedTurn(Role.USER, "hi")
    assert convert({"data": "hello"}, "response_text", shared) == SharedTurn(Role.ASSISTANT, "hello")
    assert isinstance(convert({"data": "hi"}, "prompt_transcript"), InputLost)


def test_publishes_have_the_topic_contract_shapes_and_a_down_bridge_raises() -> None:
    async def scenario() -> None:
        client = FakeClient()
        port = BridgePort(client, AgentConfig())
        await port.setup()
        assert client.advertised["response_voice"] == "by_your_command_msgs/msg/AudioChunk"
        assert client.subscribed["prompt_voice"] == "by_your_command_msgs/msg/AudioDataUtterance"
        await port.publish_voice(VoiceChunk("a-1-1", b"\x01\x00\xff\xff", 24000, True, 1_800_000_000.5))
        await port.publish_interruption("a-1-1", "barge_in", 1_800_000_001.25)
        await port.publish_metrics(TurnMetrics("a", "c", 1, 1, "voice", "completed", 12.5, 80.0))
        voice, interruption, metrics = client.published
        assert voice == (
            "response_voice",
            {
                "header": {"stamp": {"sec": 1_800_000_000, "nanosec": 500_000_000}, "frame_id": ""},
                "sample_rate": 24000,
                "channels": 1,
                "stream_id": "a-1-1",
                "end_of_stream": True,
                "data": [1, -1],
            },
        )
        assert interruption[1]["stream_id"] == "a-1-1" and interruption[1]["reason"] == "barge_in"
        assert json.loads(metrics[1]["data"])["first_audio_ms"] == 12.5
        client.down = True
        with pytest.raises(PortUnavailable):
            await port.publish_text("x")

    asyncio.run(scenario())


def test_losses_pass_through_and_a_stopped_client_closes_the_port() -> None:
    async def scenario() -> list[object]:
        client = FakeClient(Lost("prompt_voice", "audio", None, "connection to the bridge lost", 0.0))
        port = BridgePort(client, AgentConfig())
        seen: list[object] = []
        with pytest.raises(PortClosed):
            async for item in port.inputs():
                seen.append(item)
        return seen

    assert asyncio.run(scenario()) == [InputLost("prompt_voice", None, "connection to the bridge lost")]


def test_a_command_agent_does_not_publish_the_transcript() -> None:
    async def scenario() -> FakeClient:
        client = FakeClient()
        port = BridgePort(client, AgentConfig(role=AgentRole.COMMAND, context_source=ContextSource.SHARED))
        await port.setup()
        await port.publish_transcript("x")
        await port.publish_text("y")
        return client

    client = asyncio.run(scenario())
    assert client.published == [] and "prompt_transcript" not in client.advertised


def test_a_camera_frame_keeps_its_header_and_a_bad_header_is_lost() -> None:
    jpeg = base64.b64encode(b"\xff\xd8").decode()
    header = {"stamp": {"sec": 1_800_000_000, "nanosec": 250_000_000}, "frame_id": "camera_optical"}
    frame = convert({"header": header, "format": "jpeg", "data": jpeg}, "camera_forwarded")
    assert frame == CameraFrame(b"\xff\xd8", 1_800_000_000.25, "camera_optical")
    for bad in (
        {"stamp": {"sec": 1, "nanosec": 1_000_000_000}},
        {"stamp": {"sec": "1"}},
        {"frame_id": 5},
        "header",
    ):
        lost = convert({"header": bad, "format": "jpeg", "data": jpeg}, "camera_forwarded")
        assert isinstance(lost, InputLost) and lost.reason.startswith("invalid message"), (bad, lost)


def test_detections_are_published_only_by_an_agent_that_has_them_on() -> None:
    cup = Detection("cup", (100.0, 200.0, 500.0, 600.0))
    frame = FrameInfo(640, 480, 1_800_000_000.25, "camera_optical")

    async def scenario(config: AgentConfig) -> FakeClient:
        client = FakeClient()
        port = BridgePort(client, config)
        await port.setup()
        await port.publish_detections(DetectionReport("command", (cup,), frame))
        await port.publish_detections(DetectionReport("command", (cup,), None))  # no frame: JSON only
        return client

    off = asyncio.run(scenario(AgentConfig()))
    assert "detections" not in off.advertised and off.published == []

    on = asyncio.run(scenario(AgentConfig(detections=True)))
    assert on.advertised["detections"] == "std_msgs/msg/String" and "detections_2d" not in on.advertised
    [(topic, first), (_, second)] = on.published
    assert topic == "detections"
    assert json.loads(first["data"])["detections"][0]["box"] == [128.0, 48.0, 384.0, 240.0]
    assert json.loads(second["data"])["detections"][0]["box"] is None

    config = AgentConfig(detections=True, topics=Topics(detections_2d="detections_2d"))
    both = asyncio.run(scenario(config))
    assert both.advertised["detections_2d"] == "vision_msgs/msg/Detection2DArray"
    assert [topic for topic, _ in both.published] == ["detections", "detections_2d", "detections"]
    array = both.published[1][1]
    assert array["header"]["frame_id"] == "camera_optical" and len(array["detections"]) == 1
