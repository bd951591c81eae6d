"""A fake robot for the runtime's tests: inputs the test pushes, publishes it records (with the
virtual time of each), and helpers that speak like our VAD (chunks paced in virtual time)."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass, field
from typing import Any

from fake_provider import FakeFactory
from virtual_time import VirtualClock

from by_your_command.agents.config import AgentConfig
from by_your_command.agents.inputs import CommandStatus, PlaybackStatus, RobotInput, UtteranceChunk
from by_your_command.agents.interruptions import Transcriber
from by_your_command.agents.metrics import MetricsRecord, SessionMetrics, TurnMetrics
from by_your_command.agents.port import DetectionReport, PlayerAction, PortUnavailable, VoiceChunk
from by_your_command.agents.runtime import AgentRuntime
from by_your_command.commands.processor import CommandProcessor

_CLOSE = object()


@dataclass
class FakePort:
    published: list[tuple[float, str, Any]] = field(default_factory=list)  # (time, kind, payload)
    unavailable: bool = False  # publishes raise PortUnavailable
    # The real command processor answering command requests as the node does (verdicts with the
    # request's id, index and count); None: the test answers them itself.
    processor: CommandProcessor | None = None

    def __post_init__(self) -> None:
        self._inputs: asyncio.Queue[object] = asyncio.Queue()

    def push(self, item: RobotInput) -> None:
        self._inputs.put_nowait(item)

    def close(self) -> None:
        self._inputs.put_nowait(_CLOSE)

    async def inputs(self) -> AsyncIterator[RobotInput]:
        while True:
            item = await self._inputs.get()
            if item is _CLOSE:
                return
            yield item  # type: ignore[misc]

    async def _record(self, kind: str, payload: Any) -> None:
        if self.unavailable:
            raise PortUnavailable("bridge down")
        self.published.append((asyncio.get_running_loop().time(), kind, payload))

    async def publish_voice(self, chunk: VoiceChunk) -> None:
        await self._record("voice", chunk)

    async def publish_text(self, text: str) -> None:
        await self._record("text", text)

    async def publish_cmd(self, text: str) -> None:
        await self._record("cmd", text)

    async def publish_command_request(self, request_id: str, text: str) -> None:
        await self._record("request", (request_id, text))
        if self.processor is not None:
            verdicts = self.processor.process(text, asyncio.get_running_loop().time())
            for index, v in enumerate(verdicts):
                topic = "" if v.route is None else v.route.destination.value
                self.push(
                    CommandStatus(
                        v.raw, v.command, v.accepted, v.reason, topic, request_id, index, len(verdicts)
                    )
                )

    def requests(self) -> list[str]:
        """The texts of the command requests published, in order."""
        return [text for _, text in self.of("request")]

    def verdict(self, index: int, accepted: bool = True, reason: str = "arm_preset") -> CommandStatus:
        """The processor's only verdict on request `index` (the one command in its text)."""
        request_id, text = self.of("request")[index]
        return CommandStatus(text, text if accepted else "", accepted, reason, "", request_id, 0, 1)

    async def call_service(
        self, request_id: str, service: str, service_type: str, args: dict[str, Any]
    ) -> None:
        await self._record("service", (request_id, service, service_type, args))

    async def send_action_goal(
        self, request_id: str, action: str, action_type: str, args: dict[str, Any]
    ) -> None:
        await self._record("goal", (request_id, action, action_type, args))

    async def cancel_action_goal(self, request_id: str, action: str) -> None:
        await self._record("cancel", (request_id, action))

    async def publish_tool_message(self, topic: str, msg_type: str, msg: dict[str, Any]) -> None:
        await self._record("tool_message", (topic, msg_type, msg))

    async def publish_interruption(
        self, stream_id: str, reason: str, stamp: float, action: PlayerAction = PlayerAction.CUT
    ) -> None:
        kind = {PlayerAction.CUT: "interruption", PlayerAction.PAUSE: "pause", PlayerAction.RESUME: "resume"}
        await self._record(kind[action], (stream_id, reason))

    async def publish_transcript(self, text: str) -> None:
        await self._record("transcript", text)

    async def publish_metrics(self, record: MetricsRecord) -> None:
        await self._record("metrics", record)

    async def publish_detections(self, detections: DetectionReport) -> None:
        await self._record("detections", detections)

    # --- views ---
    def of(self, kind: str) -> list[Any]:
        return [payload for _, kind_, payload in self.published if kind_ == kind]

    def voice(self) -> list[VoiceChunk]:
        return self.of("voice")

    def streams(self) -> list[str]:
        seen: list[str] = []
        for chunk in self.voice():
            if chunk.stream_id not in seen:
                seen.append(chunk.stream_id)
        return seen

    def stream_audio(self, stream_id: str) -> bytes:
        return b"".join(chunk.pcm for chunk in self.voice() if chunk.stream_id == stream_id)

    def turns(self) -> list[TurnMetrics]:
        return [r for r in self.of("metrics") if isinstance(r, TurnMetrics)]

    def sessions(self) -> list[SessionMetrics]:
        return [r for r in self.of("metrics") if isinstance(r, SessionMetrics)]

    def first_time(self, kind: str) -> float:
        return next(at for at, kind_, _ in self.published if kind_ == kind)


def silence_pcm(seconds: float, rate: int = 16000, value: int = 300) -> bytes:
    return value.to_bytes(2, "little", signed=True) * int(round(seconds * rate))


async def speak(
    port: FakePort,
    utterance_id: int,
    seconds: float,
    chunk_s: float = 0.1,
    end: bool = True,
    rate: int = 16000,
    unvoiced_s: float = 0.0,
) -> None:
    """Push an utterance as the VAD does: one chunk every chunk_s of (virtual) time, end marker last;
    its first `unvoiced_s` (the VAD's pre-roll) are not speech."""
    chunks = max(1, round(seconds / chunk_s))
    chunk_samples = int(chunk_s * rate)
    for sequence in range(chunks):
        last = end and sequence == chunks - 1
        unvoiced = min((sequence + 1) * chunk_samples, int(unvoiced_s * rate))
        port.push(UtteranceChunk(silence_pcm(chunk_s, rate), rate, utterance_id, sequence, last, unvoiced))
        await asyncio.sleep(chunk_s)


def playing(stream_id: str, played_ms: int, **flags: bool) -> PlaybackStatus:
    return PlaybackStatus(stream_id, played_ms, queued_ms=1000, speaking=True, **flags)


@dataclass
class Agent:
    runtime: AgentRuntime
    port: FakePort
    factory: FakeFactory
    task: asyncio.Task[None]

    async def stop(self) -> None:
        self.port.close()
        await asyncio.wait_for(self.task, 30)


@contextlib.asynccontextmanager
async def running_agent(
    config: AgentConfig,
    factory: FakeFactory,
    processor: CommandProcessor | None = None,
    transcriber: Transcriber | None = None,
) -> AsyncIterator[Agent]:
    port = FakePort(processor=processor)
    runtime = AgentRuntime(config, "You are a test robot.", port, factory, VirtualClock(), transcriber)
    task = asyncio.create_task(runtime.run())
    agent = Agent(runtime, port, factory, task)
    try:
        yield agent
    finally:
        if not task.done():
            await agent.stop()


def calls_named(names: list[str], name: str) -> Iterator[int]:
    return (index for index, value in enumerate(names) if value == name)
