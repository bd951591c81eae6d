"""The runtime's only door to the robot: typed inputs in, typed publishes out.

The bridge adapter (`bridge_port.py`) implements it over the rosbridge client; tests use a fake.
A publish raises `PortUnavailable` (or any ConnectionError) when it cannot be sent now: the runtime
counts and logs it, and never waits for the bridge to come back to decide a turn.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Protocol

from by_your_command.agents.detections import Detection, FrameInfo
from by_your_command.agents.inputs import RobotInput
from by_your_command.agents.metrics import MetricsRecord


class PortUnavailable(ConnectionError):
    """The robot side cannot take a message right now."""


class PortClosed(ConnectionError):
    """The robot side is gone for good (closed, or refused us): `inputs()` raises it to stop the agent."""


@dataclass(frozen=True)
class VoiceChunk:
    """One `response_voice` chunk: a reply's audio with its rate; `end_of_stream` on the last one."""

    stream_id: str
    pcm: bytes  # mono int16 LE
    sample_rate: int
    end_of_stream: bool = False
    stamp: float = 0.0  # wall-clock seconds of the first sample (synthesis time)


class PlayerAction(IntEnum):
    """Interruption.action: what the player does to the reply named."""

    CUT = 0
    PAUSE = 1
    RESUME = 2


@dataclass(frozen=True)
class DetectionReport:
    """Object detections from one reply, with the frame the model was shown (None: no frame)."""

    agent_id: str
    detections: tuple[Detection, ...]
    frame: FrameInfo | None


class RobotPort(Protocol):
    async def publish_voice(self, chunk: VoiceChunk) -> None: ...

    async def publish_text(self, text: str) -> None:
        """`response_text`: the assistant's words, and reports a person should see."""

    async def publish_cmd(self, text: str) -> None:
        """`response_cmd`: one command for the command processor."""

    async def publish_command_request(self, request_id: str, text: str) -> None:
        """`command_request`: commands whose verdicts come back on `command_status` with this id."""

    async def publish_interruption(
        self, stream_id: str, reason: str, stamp: float, action: PlayerAction = PlayerAction.CUT
    ) -> None:
        """`interruption_signal`: cut (or pause, or resume) `stream_id` at the player now."""

    async def publish_transcript(self, text: str) -> None:
        """`prompt_transcript`: what the user said."""

    async def publish_metrics(self, record: MetricsRecord) -> None: ...

    async def publish_detections(self, detections: DetectionReport) -> None:
        """`detections`: boxes the model found, in pixels of the frame it was shown (JSON)."""

    async def call_service(
        self, request_id: str, service: str, service_type: str, args: dict[str, Any]
    ) -> None:
        """A robot tool's service request; its response comes back as CallReplied(request_id)."""

    async def send_action_goal(
        self, request_id: str, action: str, action_type: str, args: dict[str, Any]
    ) -> None:
        """A robot tool's action goal; CallFeedback and one CallReplied(request_id) come back."""

    async def cancel_action_goal(self, request_id: str, action: str) -> None:
        """Cancel the goal sent with `request_id` (its CallReplied still comes)."""

    async def publish_tool_message(self, topic: str, msg_type: str, msg: dict[str, Any]) -> None:
        """A robot tool's topic message (the bridge's allow-list decides)."""

    def inputs(self) -> AsyncIterator[RobotInput]:
        """Inputs in the order the robot side delivers them; ends when the port closes."""
