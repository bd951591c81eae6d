"""The RobotPort over the rosbridge client: rosbridge JSON in and out (docs/topics.md, protocol.md).

Every message from the bridge is untrusted: one that does not convert comes out as `InputLost`
(reason "invalid message: …"), so the runtime counts it. `Lost` deliveries become `InputLost` too.
A publish while the bridge is down raises PortUnavailable; a stopped client ends `inputs()` with
PortClosed. Empty topic names in the config switch an input or output off.
"""

from __future__ import annotations

import base64
import binascii
import json
from collections.abc import AsyncIterator, Callable
from typing import Any, Protocol

import numpy as np

from by_your_command.agents.config import AgentConfig, AgentRole, ContextSource
from by_your_command.agents.detections import detection2d_array, detections_json
from by_your_command.agents.inputs import (
    Attention,
    AttentionChanged,
    CallFeedback,
    CallReplied,
    CameraFrame,
    CommandStatus,
    ConversationReset,
    InputLost,
    PlaybackStatus,
    PromptText,
    RobotInput,
    SafetyStop,
    SharedTurn,
    ToolCatalog,
    UtteranceChunk,
    VoiceActivity,
)
from by_your_command.agents.metrics import MetricsRecord
from by_your_command.agents.port import (
    DetectionReport,
    PlayerAction,
    PortClosed,
    PortUnavailable,
    VoiceChunk,
)
from by_your_command.agents.provider import Role
from by_your_command.bridge.client_messages import (
    BridgeUnavailable,
    ClientStopped,
    Delivery,
    GoalFeedback,
    GoalResult,
    Lost,
    ServiceReply,
)

AUDIO_CHUNK = "by_your_command_msgs/msg/AudioChunk"
UTTERANCE = "by_your_command_msgs/msg/AudioDataUtterance"
INTERRUPTION = "by_your_command_msgs/msg/Interruption"
PLAYBACK = "by_your_command_msgs/msg/PlaybackStatus"
VERDICT = "by_your_command_msgs/msg/CommandVerdict"
COMMAND_REQUEST = "by_your_command_msgs/msg/CommandRequest"
STRING = "std_msgs/msg/String"
SAFETY_STOP = "by_your_command_msgs/msg/SafetyStop"
BOOL = "std_msgs/msg/Bool"
IMAGE = "sensor_msgs/msg/CompressedImage"
DETECTION_2D_ARRAY = "vision_msgs/msg/Detection2DArray"


class BridgeLike(Protocol):
    """The parts of bridge.client.BridgeClient this port uses."""

    async def subscribe(self, topic: str, msg_type: str | None = None) -> None: ...

    async def advertise(self, topic: str, msg_type: str) -> None: ...

    async def publish(self, topic: str, msg: dict[str, Any]) -> None: ...

    async def receive(self, timeout: float | None = None) -> Delivery: ...

    async def call_service(
        self,
        service: str,
        args: dict[str, Any],
        request_id: str,
        service_type: str | None = None,
        timeout_s: float | None = None,
    ) -> None: ...

    async def send_action_goal(
        self, action: str, action_type: str, args: dict[str, Any], request_id: str
    ) -> None: ...

    async def cancel_action_goal(self, action: str, request_id: str) -> None: ...


class BadMessage(ValueError):
    pass


def _field(msg: dict[str, Any], name: str, kind: type, default: Any = None) -> Any:
    value = msg.get(name, default)
    if kind is int and isinstance(value, bool) or not isinstance(value, kind):
        raise BadMessage(f"{name}: expected {kind.__name__}")
    return value


def _safety_stop(msg: dict[str, Any]) -> SafetyStop:
    utterance_id = _field(msg, "utterance_id", int, 0)
    if not 0 <= utterance_id < 2**64:
        raise BadMessage("utterance_id: outside uint64")
    return SafetyStop(_field(msg, "phrase", str)[:200], utterance_id)


def _pcm(values: Any) -> bytes:
    if not isinstance(values, list):
        raise BadMessage("int16_data: expected a list")
    try:
        samples = np.asarray(values, dtype=np.int64)
    except (TypeError, ValueError):
        raise BadMessage("int16_data: expected integers") from None
    if samples.ndim != 1 or (samples.size and (samples.min() < -32768 or samples.max() > 32767)):
        raise BadMessage("int16_data: values outside int16")
    return samples.astype("<i2").tobytes()


def _utterance(msg: dict[str, Any]) -> RobotInput:
    if _field(msg, "channels", int, 1) not in (0, 1):
        raise BadMessage("channels: the pipeline is mono")
    return UtteranceChunk(
        _pcm(msg.get("int16_data", [])),
        _field(msg, "sample_rate", int, 16000),
        _field(msg, "utterance_id", int, 0),
        _field(msg, "chunk_sequence", int, 0),
        _field(msg, "is_utterance_end", bool, False),
        _field(msg, "unvoiced_samples", int, 0),
    )


def _playback(msg: dict[str, Any]) -> RobotInput:
    return PlaybackStatus(
        _field(msg, "stream_id", str, ""),
        _field(msg, "played_ms", int, 0),
        _field(msg, "queued_ms", int, 0),
        _field(msg, "speaking", bool, False),
        _field(msg, "finished", bool, False),
        _field(msg, "interrupted", bool, False),
        _field(msg, "starved", bool, False),
        _field(msg, "paused", bool, False),
    )


def _attention(msg: dict[str, Any]) -> RobotInput:
    state = _field(msg, "data", str)
    try:
        return AttentionChanged(Attention(state.strip().lower()))
    except ValueError:
        raise BadMessage(f"data: unknown attention state {state[:40]!r}") from None


def _image(msg: dict[str, Any]) -> RobotInput:
    if "jpeg" not in _field(msg, "format", str, "").lower():
        raise BadMessage("format: only jpeg frames are forwarded to providers")
    header = _field(msg, "header", dict, {})
    stamp = _field(header, "stamp", dict, {})
    sec, nanosec = _field(stamp, "sec", int, 0), _field(stamp, "nanosec", int, 0)
    if not 0 <= nanosec < 1_000_000_000:
        raise BadMessage("header.stamp.nanosec: must be 0..999999999")
    try:
        jpeg = base64.b64decode(_field(msg, "data", str), validate=True)
    except binascii.Error:
        raise BadMessage("data: invalid base64") from None
    return CameraFrame(jpeg, sec + nanosec / 1e9, _field(header, "frame_id", str, "")[:256])


def _verdict(msg: dict[str, Any]) -> RobotInput:
    return CommandStatus(
        _field(msg, "raw", str, ""),
        _field(msg, "command", str, ""),
        _field(msg, "accepted", bool, False),
        _field(msg, "reason", str, ""),
        _field(msg, "topic", str, ""),
        _field(msg, "request_id", str, ""),
        _field(msg, "index", int, 0),
        _field(msg, "count", int, 1),
    )


def _call_input(delivery: ServiceReply | GoalResult | GoalFeedback) -> RobotInput:
    """A reply to one of our robot tool requests: ids are ours as strings (another id is stray)."""
    request_id = str(delivery.id)
    if isinstance(delivery, GoalFeedback):
        return CallFeedback(request_id, delivery.values)
    if isinstance(delivery, ServiceReply):
        return CallReplied(request_id, delivery.ok, delivery.values, delivery.error[:500], delivery.code)
    return CallReplied(
        request_id, delivery.ok, delivery.values, delivery.error[:500], delivery.code, delivery.status, True
    )


def _stamp(wall: float) -> dict[str, Any]:
    sec = int(wall)
    return {"stamp": {"sec": sec, "nanosec": int((wall - sec) * 1e9)}, "frame_id": ""}


class BridgePort:
    def __init__(self, client: BridgeLike, config: AgentConfig) -> None:
        self._client = client
        topics = config.topics
        self._topics = topics
        self._inputs: dict[str, tuple[str, Callable[[dict[str, Any]], RobotInput]]] = {}
        self._add(topics.prompt_voice, UTTERANCE, _utterance)
        self._add(topics.prompt_text, STRING, lambda msg: PromptText(_field(msg, "data", str)))
        self._add(topics.voice_activity, BOOL, lambda msg: VoiceActivity(_field(msg, "data", bool)))
        self._add(topics.playback_status, PLAYBACK, _playback)
        self._add(topics.attention_state, STRING, _attention)
        self._add(topics.camera, IMAGE, _image)
        self._add(topics.command_status, VERDICT, _verdict)
        self._add(topics.conversation_reset, STRING, lambda msg: ConversationReset(_field(msg, "data", str)))
        self._add(topics.safety_stop, SAFETY_STOP, _safety_stop)
        if config.role is AgentRole.TOOLS:
            self._add(topics.robot_tools, STRING, lambda msg: ToolCatalog(_field(msg, "data", str)))
        self._tool_topics: set[str] = set()  # advertised for robot tools of kind topic
        if config.context_source is ContextSource.SHARED:  # the conversation agent's turns
            self._add(
                topics.prompt_transcript, STRING, lambda msg: SharedTurn(Role.USER, _field(msg, "data", str))
            )
            self._add(
                topics.response_text, STRING, lambda msg: SharedTurn(Role.ASSISTANT, _field(msg, "data", str))
            )
        self._outputs = {
            topics.response_voice: AUDIO_CHUNK,
            topics.interruption_signal: INTERRUPTION,
            topics.response_cmd: STRING,
            topics.metrics: STRING,
        }
        if config.context_source is ContextSource.OWN:  # only the authority publishes the transcript
            self._outputs[topics.response_text] = STRING
            self._outputs[topics.prompt_transcript] = STRING
        if config.role is AgentRole.TOOLS:  # tool calls' commands, answered by request id
            self._outputs[topics.command_request] = COMMAND_REQUEST
        if config.detections:
            self._outputs[topics.detections] = STRING
            self._outputs[topics.detections_2d] = DETECTION_2D_ARRAY
        self._outputs.pop("", None)

    def _add(self, topic: str, msg_type: str, convert: Callable[[dict[str, Any]], RobotInput]) -> None:
        if topic:
            self._inputs[topic] = (msg_type, convert)

    async def setup(self) -> None:
        """Subscribe and advertise (the client replays both after every reconnect)."""
        for topic, (msg_type, _) in self._inputs.items():
            await self._client.subscribe(topic, msg_type)
        for topic, msg_type in self._outputs.items():
            await self._client.advertise(topic, msg_type)

    async def inputs(self) -> AsyncIterator[RobotInput]:
        while True:
            try:
                delivery = await self._client.receive()
            except ClientStopped as stopped:
                raise PortClosed(f"the bridge client stopped: {stopped}") from stopped
            yield self.convert(delivery)

    def convert(self, delivery: Delivery) -> RobotInput:
        if isinstance(delivery, Lost):
            return InputLost(delivery.topic, delivery.count, delivery.reason)
        if isinstance(delivery, (ServiceReply, GoalResult, GoalFeedback)):
            return _call_input(delivery)
        known = self._inputs.get(delivery.topic)
        if known is None:
            return InputLost(delivery.topic, 1, "invalid message: not a topic this agent reads")
        try:
            return known[1](delivery.msg)
        except BadMessage as error:
            return InputLost(delivery.topic, 1, f"invalid message: {error}")

    async def _publish(self, topic: str, msg: dict[str, Any]) -> None:
        if topic not in self._outputs:
            return  # switched off in the config (or not this agent's to publish)
        try:
            await self._client.publish(topic, msg)
        except BridgeUnavailable as error:
            raise PortUnavailable(str(error)) from error

    async def call_service(
        self, request_id: str, service: str, service_type: str, args: dict[str, Any]
    ) -> None:
        try:
            await self._client.call_service(service, args, request_id, service_type)
        except BridgeUnavailable as error:
            raise PortUnavailable(str(error)) from error

    async def send_action_goal(
        self, request_id: str, action: str, action_type: str, args: dict[str, Any]
    ) -> None:
        try:
            await self._client.send_action_goal(action, action_type, args, request_id)
        except BridgeUnavailable as error:
            raise PortUnavailable(str(error)) from error

    async def cancel_action_goal(self, request_id: str, action: str) -> None:
        try:
            await self._client.cancel_action_goal(action, request_id)
        except BridgeUnavailable as error:
            raise PortUnavailable(str(error)) from error

    async def publish_tool_message(self, topic: str, msg_type: str, msg: dict[str, Any]) -> None:
        try:
            if topic not in self._tool_topics:
                await self._client.advertise(topic, msg_type)
                self._tool_topics.add(topic)
            await self._client.publish(topic, msg)
        except BridgeUnavailable as error:
            raise PortUnavailable(str(error)) from error

    async def publish_voice(self, chunk: VoiceChunk) -> None:
        data = np.frombuffer(chunk.pcm, dtype="<i2").tolist()
        msg = {
            "header": _stamp(chunk.stamp),
            "sample_rate": chunk.sample_rate,
            "channels": 1,
            "stream_id": chunk.stream_id,
            "end_of_stream": chunk.end_of_stream,
            "data": data,
        }
        await self._publish(self._topics.response_voice, msg)

    async def publish_text(self, text: str) -> None:
        await self._publish(self._topics.response_text, {"data": text})

    async def publish_cmd(self, text: str) -> None:
        await self._publish(self._topics.response_cmd, {"data": text})

    async def publish_command_request(self, request_id: str, text: str) -> None:
        await self._publish(self._topics.command_request, {"request_id": request_id, "text": text})

    async def publish_interruption(
        self, stream_id: str, reason: str, stamp: float, action: PlayerAction = PlayerAction.CUT
    ) -> None:
        msg = {"header": _stamp(stamp), "stream_id": stream_id, "reason": reason, "action": int(action)}
        await self._publish(self._topics.interruption_signal, msg)

    async def publish_transcript(self, text: str) -> None:
        await self._publish(self._topics.prompt_transcript, {"data": text})

    async def publish_metrics(self, record: MetricsRecord) -> None:
        await self._publish(self._topics.metrics, {"data": json.dumps(record.as_dict())})

    async def publish_detections(self, detections: DetectionReport) -> None:
        payload = detections_json(detections.detections, detections.frame, detections.agent_id)
        await self._publish(self._topics.detections, {"data": json.dumps(payload)})
        frame = detections.frame
        if self._topics.detections_2d and frame is not None and frame.width > 0 and frame.height > 0:
            # pixel boxes need the frame's size: without it only the JSON topic carries them
            await self._publish(self._topics.detections_2d, detection2d_array(detections.detections, frame))
