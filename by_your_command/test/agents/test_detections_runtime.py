"""Detections in replies reach `detections` (in pixels of the frame the model was shown), never
`response_cmd`; an agent without `detections: true` drops them (counted)."""

from __future__ import annotations

import asyncio
import io

import pytest
from fake_port import running_agent, speak
from fake_provider import FakeFactory, Script, spoken_reply
from PIL import Image
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig, AgentRole, ContextSource
from by_your_command.agents.detections import Detection, FrameInfo
from by_your_command.agents.events import AssistantText, ResponseDone, ResponseStatus
from by_your_command.agents.inputs import CameraFrame
from by_your_command.agents.port import DetectionReport

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

BOXES = 'lookup\n```json\n[{"box_2d": [100, 200, 500, 600], "label": "cup"}]\n```'
COMMAND = AgentConfig(
    agent_id="command", role=AgentRole.COMMAND, context_source=ContextSource.SHARED, detections=True
)


def jpeg(width: int, height: int) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (width, height)).save(buffer, format="JPEG")
    return buffer.getvalue()


def text_reply(response_id: str, text: str) -> Script:
    return [
        (0.1, AssistantText(response_id, "i", text, final=True)),
        (0.0, ResponseDone(response_id, ResponseStatus.COMPLETED)),
    ]


def test_command_agent_publishes_boxes_in_pixels_and_routes_only_the_command() -> None:
    async def scenario() -> None:
        factory = FakeFactory(text_reply("r1", BOXES), text_reply("r2", BOXES))
        async with running_agent(COMMAND, factory) as agent:
            agent.port.push(CameraFrame(jpeg(640, 480), 1_800_000_000.5, "camera_optical"))
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            agent.port.push(CameraFrame(jpeg(320, 200), 1_800_000_009.0, "other"))  # never shown
            agent.port.push(CameraFrame(b"", 0.0, "empty"))  # refused: not a frame
            await asyncio.sleep(10.0)  # stale by the next turn: not sent
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert agent.port.of("cmd") == ["lookup", "lookup"]
        shown = FrameInfo(640, 480, 1_800_000_000.5, "camera_optical")
        cup = Detection("cup", (100.0, 200.0, 500.0, 600.0))
        assert agent.port.of("detections") == [DetectionReport("command", (cup,), shown)] * 2
        assert agent.runtime.counters.detections_published == 2

    run_virtual(scenario())


def test_without_detections_enabled_boxes_are_dropped_and_never_routed() -> None:
    async def scenario() -> None:
        only_boxes = '[{"box_2d": [1, 2, 300, 400], "label": "cup"}, {"box_2d": [9, 9, 9, 9], "label": "x"}]'
        factory = FakeFactory(text_reply("r1", only_boxes), text_reply("r2", 'wave [{"box_2d": [1, 2'))
        config = AgentConfig(role=AgentRole.COMMAND, context_source=ContextSource.SHARED)
        async with running_agent(config, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            await speak(agent.port, 2, seconds=0.3)  # box JSON cut off: not a command either
            await asyncio.sleep(1.0)
            await agent.stop()
        assert agent.port.of("cmd") == [] and agent.port.of("detections") == []
        counters = agent.runtime.counters
        assert (counters.detections_dropped, counters.detections_refused) == (1, 1)

    run_virtual(scenario())


def test_a_speaking_agent_says_the_words_and_publishes_the_boxes_without_a_frame() -> None:
    async def scenario() -> None:
        reply = spoken_reply("r1", seconds=0.2, text=f"I see a cup. {BOXES}")
        factory = FakeFactory(reply)
        async with running_agent(AgentConfig(detections=True), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert agent.port.of("text") == ["I see a cup. lookup"]
        [report] = agent.port.of("detections")
        assert report.frame is None and [d.label for d in report.detections] == ["cup"]

    run_virtual(scenario())
