"""Gemini features on top of the provider basics, through the official SDK against the emulator:
toolCallCancellation (provider events, and the runtime with a real provider), and the websocket
settings the SDK passes on from `async_client_args` (google-genai 2.33 and 3.x alike)."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable
from typing import Any

import pytest
from fake_port import FakePort

from by_your_command.agents.config import AgentConfig, AgentRole
from by_your_command.agents.events import (
    AssistantAudio,
    ProviderError,
    ResponseDone,
    ToolCall,
    ToolCallCancelled,
)
from by_your_command.agents.inputs import PromptText, UtteranceChunk
from by_your_command.agents.provider import SessionSetup, ToolResult
from by_your_command.agents.providers.gemini_live.provider import GeminiLiveConfig, GeminiLiveProvider
from by_your_command.agents.providers.gemini_live.resumption import ResumptionHandles
from by_your_command.agents.robot_tool import ROBOT_COMMAND_TOOL
from by_your_command.agents.runtime import AgentRuntime
from by_your_command.emulators.gemini_live import GeminiLiveEmulator, start
from by_your_command.emulators.gemini_script import CallTool, Say, Script, Turn
from by_your_command.emulators.gemini_wire import field_value

pytestmark = [pytest.mark.unit, pytest.mark.timeout(90)]

KEY = "test-key-1234567890"
TOOL_SETUP = SessionSetup("You are a robot.", tools=(ROBOT_COMMAND_TOOL,))
WAVE = CallTool("robot_command", '{"command": "wave"}', Say("I waved."))


def settings(emulator: GeminiLiveEmulator, **config: Any) -> GeminiLiveConfig:
    return GeminiLiveConfig(base_url=emulator.base_url, ca_file=str(emulator.cert_file), **config)


async def until(condition: Callable[[], bool], what: str, timeout_s: float = 30.0) -> None:
    """Wait for a condition (generous: the machine may be loaded), never for a fixed time."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.01)


async def connected(script: Script, **config: Any) -> tuple[GeminiLiveEmulator, GeminiLiveProvider]:
    emulator = await start(script=script)
    provider = GeminiLiveProvider(settings(emulator, **config), api_key=KEY)
    await provider.connect(TOOL_SETUP)
    return emulator, provider


async def events_until(provider: GeminiLiveProvider, done: Callable[[object], bool]) -> list[object]:
    taken: list[object] = []
    async for event in provider.events():
        taken.append(event)
        if done(event):
            return taken
    raise AssertionError(f"events ended early: {taken}")


# ---- toolCallCancellation at the provider -------------------------------------------------------


def test_a_scripted_cancellation_becomes_a_typed_event_and_the_result_is_never_sent() -> None:
    async def main() -> None:
        emulator, provider = await connected(Script(turns=(Turn(WAVE, cancel_after_ms=100),)))
        try:
            await provider.send_text("wave")
            got = await events_until(provider, lambda e: isinstance(e, ToolCallCancelled))
            [call] = [e for e in got if isinstance(e, ToolCall)]
            assert got[-1] == ToolCallCancelled((call.call_id,))
            await provider.send_tool_results([ToolResult(call.call_id, json.dumps({"accepted": True}))])
            await provider.send_text("still there?")  # the session goes on
            await events_until(provider, lambda e: isinstance(e, ResponseDone))
            assert emulator.received_of("toolResponse") == []
        finally:
            await provider.close()
            await emulator.stop()

    asyncio.run(main())


def test_user_speech_while_a_call_waits_cancels_it_like_the_real_server() -> None:
    async def main() -> None:
        emulator, provider = await connected(Script(turns=(Turn(WAVE), Turn(Say("Yes?")))))
        try:
            await provider.send_text("wave")
            [call] = [e for e in await events_until(provider, lambda e: isinstance(e, ToolCall))]
            assert isinstance(call, ToolCall)
            await provider.send_audio(b"\x00\x01" * 1600)  # activityStart: the user cuts in
            got = await events_until(provider, lambda e: isinstance(e, ToolCallCancelled))
            assert got[-1] == ToolCallCancelled((call.call_id,))  # type: ignore[union-attr]
        finally:
            await provider.close()
            await emulator.stop()

    asyncio.run(main())


# ---- websocket settings through async_client_args ------------------------------------------------


def test_ping_and_message_size_settings_reach_the_websocket() -> None:
    async def main() -> None:
        emulator, provider = await connected(
            Script(turns=(Turn(Say("A reply far longer than one kilobyte of audio.")),)),
            ping_interval_s=7.0,
            ping_timeout_s=9.0,
            max_message_bytes=2048,
        )
        try:
            socket = provider._session._ws  # the SDK's websocket: what the settings must reach
            assert (socket.ping_interval, socket.ping_timeout) == (7.0, 9.0)
            await provider.send_text("talk")
            got = await events_until(provider, lambda e: isinstance(e, ProviderError))
            # the first audio message (~6 KB of base64) is over the limit: the client closes (1009)
            assert isinstance(got[-1], ProviderError) and got[-1].code == "server_closed"
            assert not any(isinstance(e, AssistantAudio) for e in got)
        finally:
            await provider.close()
            await emulator.stop()

    asyncio.run(main())


# ---- the runtime with the real provider ----------------------------------------------------------


def test_the_runtime_sends_no_result_for_a_cancelled_call_and_ends_the_turn() -> None:
    """Tool mode end to end: the command is routed, the server cancels the call, the robot's late
    verdict is not answered, the turn ends `cancelled` and the next turn is answered."""

    async def main() -> None:
        script = Script(turns=(Turn(WAVE, cancel_after_ms=300), Turn(Say("Yes?"))))
        emulator = await start(script=script)
        handles = ResumptionHandles()
        config = AgentConfig(agent_id="robot", role=AgentRole.TOOLS, tool_verdict_timeout_s=30.0)
        port = FakePort()
        runtime = AgentRuntime(
            config,
            "You are a robot.",
            port,
            lambda: GeminiLiveProvider(settings(emulator), api_key=KEY, resumption=handles),
        )
        task = asyncio.create_task(runtime.run())
        try:
            port.push(PromptText("please wave"))
            await until(lambda: port.requests() == ["wave"], "the command routed")
            await until(lambda: runtime.counters.tool_calls_cancelled == 1, "the cancellation")
            await until(lambda: [t.outcome for t in port.turns()] == ["cancelled"], "the turn ended")
            for sequence in range(5):  # the next question is answered as usual
                port.push(UtteranceChunk(b"\x00\x01" * 1600, 16000, 7, sequence, sequence == 4))
            await until(lambda: [t.outcome for t in port.turns()] == ["cancelled", "completed"], "the answer")
            assert emulator.received_of("toolResponse") == []
            assert runtime.counters.commands_withheld == 0 and runtime.counters.tool_timeouts == 0
        finally:
            port.close()
            await asyncio.wait_for(task, 30)
            await emulator.stop()

    asyncio.run(main())


def test_a_turn_gemini_cannot_answer_fails_at_once_and_is_never_replayed() -> None:
    """An utterance of digital silence (the model declines it: a bare turnComplete with a reason),
    then an utterance without audio (the provider sends nothing): each fails now, on the same
    session, long before the reply timeout, and the next question is answered."""

    async def main() -> None:
        emulator = await start(script=Script(turns=(Turn(Say("Yes?")),)))
        config = AgentConfig(agent_id="talker", reply_timeout_s=600.0, pause_timeout_s=600.0)
        port = FakePort()
        runtime = AgentRuntime(
            config, "You are a robot.", port, lambda: GeminiLiveProvider(settings(emulator), api_key=KEY)
        )
        task = asyncio.create_task(runtime.run())
        try:
            for sequence in range(3):  # 0.3 s of zeros: a gated microphone
                port.push(UtteranceChunk(bytes(3200), 16000, 1, sequence, sequence == 2))
            await until(lambda: [t.outcome for t in port.turns()] == ["failed"], "the silent turn failed")
            port.push(UtteranceChunk(b"", 16000, 2, 0, True))
            await until(lambda: [t.outcome for t in port.turns()] == ["failed"] * 2, "the empty turn failed")
            for sequence in range(5):
                port.push(UtteranceChunk(b"\x00\x01" * 1600, 16000, 3, sequence, sequence == 4))
            await until(lambda: [t.outcome for t in port.turns()][-1:] == ["completed"], "the answer")
            assert [t.outcome for t in port.turns()] == ["failed", "failed", "completed"]
            assert len(emulator.handshakes) == 1  # no session was lost or recycled for them
            ends = [
                b for b in emulator.received_of("realtimeInput") if field_value(b, "activityEnd") is not None
            ]
            assert len(ends) == 2  # the silent turn once (never replayed), the question once
        finally:
            port.close()
            await asyncio.wait_for(task, 30)
            await emulator.stop()

    asyncio.run(main())
