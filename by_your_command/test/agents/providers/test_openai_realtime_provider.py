"""The OpenAI Realtime provider through the official SDK against the local emulator (loopback only).

Assertions are on our typed events and on what the emulator recorded the client sending; never on
the emulator's invented details (token counts, timing, ids), except values the test itself scripts.
"""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Callable, Coroutine
from dataclasses import replace
from typing import Any

import pytest
from emulated_session import is_done, run_session, sent, take_until

from by_your_command.agents.events import (
    AssistantAudio,
    AssistantText,
    AssistantTranscript,
    ProviderError,
    ResponseDone,
    ResponseStatus,
    SessionEnding,
    ToolCall,
    UserTranscript,
)
from by_your_command.agents.provider import (
    HistoryTurn,
    ProviderClosed,
    ProviderFailure,
    Role,
    SessionSetup,
    ToolResult,
    ToolSpec,
)
from by_your_command.agents.providers.openai_realtime.provider import (
    OpenAIRealtimeConfig,
    OpenAIRealtimeProvider,
)
from by_your_command.emulators.openai_realtime import OpenAIRealtimeEmulator, start
from by_your_command.emulators.openai_script import CallTool, Say, Script, Silence, Turn

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

SETUP = SessionSetup(instructions="You are a robot.")
TINY_JPEG = bytes.fromhex("ffd8ffe000104a46494600010100000100010000ffd9")
Body = Callable[[OpenAIRealtimeEmulator, OpenAIRealtimeProvider], Coroutine[Any, Any, None]]


def run(body: Body, script: Script | None = None, setup: SessionSetup = SETUP, **config: Any) -> None:
    def provider(emulator: OpenAIRealtimeEmulator) -> OpenAIRealtimeProvider:
        settings = OpenAIRealtimeConfig(websocket_base_url=emulator.websocket_base_url, **config)
        return OpenAIRealtimeProvider(settings, api_key="sk-test")

    run_session(lambda: start(script=script), provider, body, setup)


def speech(ms: int) -> bytes:
    return b"\x00\x08\x00\xf8" * (24 * ms // 2)  # 24 kHz int16


def test_voice_turn_streams_commits_and_gets_audio_transcripts_and_usage() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        events = provider.events()
        for _ in range(5):
            await provider.send_audio(speech(40))
        await provider.end_of_turn()
        got = await take_until(events, is_done)

        update = sent(emulator, "session.update")[0]["session"]
        assert update["type"] == "realtime" and update["model"] == "gpt-realtime-2.1"
        assert update["audio"]["input"]["turn_detection"] is None
        assert update["audio"]["input"]["format"] == {"type": "audio/pcm", "rate": 24000}
        assert update["audio"]["input"]["transcription"]["model"] == "gpt-realtime-whisper"
        assert update["audio"]["output"]["voice"] == "marin"
        assert update["instructions"] == "You are a robot."
        assert emulator.received_types()[1:] == ["input_audio_buffer.append"] * 5 + [
            "input_audio_buffer.commit",
            "response.create",
        ]
        assert [e.text for e in got if isinstance(e, UserTranscript)] == ["hello robot"]
        audio = [e for e in got if isinstance(e, AssistantAudio)]
        assert audio and {e.sample_rate for e in audio} == {24000}
        final = [e.text for e in got if isinstance(e, AssistantTranscript) and e.final]
        assert final == ["Hi, I am listening."]
        done = got[-1]
        assert isinstance(done, ResponseDone) and done.status is ResponseStatus.COMPLETED
        assert done.response_id == audio[0].response_id
        assert done.usage.output_audio_tokens > 0 and done.usage.input_audio_tokens > 0
        assert not [e for e in got if isinstance(e, ProviderError)]
        assert "openai-beta" not in emulator.handshakes[0].headers  # GA only

    run(body, Script(turns=(Turn(Say("Hi, I am listening."), heard="hello robot"),)))


def test_text_turn_in_a_text_session_gets_a_text_reply() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        await provider.send_text("what time is it")
        got = await take_until(provider.events(), is_done)
        created = sent(emulator, "conversation.item.create")[0]["item"]
        assert created["content"] == [{"type": "input_text", "text": "what time is it"}]
        assert sent(emulator, "session.update")[0]["session"]["output_modalities"] == ["text"]
        assert [e.text for e in got if isinstance(e, AssistantText) and e.final] == ["It is noon."]
        assert not [e for e in got if isinstance(e, AssistantAudio)]

    run(body, Script(turns=(Turn(Say("It is noon.")),)), SessionSetup("Be brief.", audio_out=False))


def test_a_context_note_joins_the_history_without_asking_for_a_reply() -> None:
    """The safety stop tells the model it was stopped: an item, and no response.create for it."""

    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        await provider.add_context('"stop" (the robot stopped)')
        await provider.send_text("are you there?")
        await take_until(provider.events(), is_done)
        items = [event["item"]["content"][0]["text"] for event in sent(emulator, "conversation.item.create")]
        assert items == ['"stop" (the robot stopped)', "are you there?"]
        assert len(sent(emulator, "response.create")) == 1  # for the question only

    run(body, Script(turns=(Turn(Say("Yes.")),)))


def test_history_is_seeded_as_text_items() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        await provider.send_text("and now?")
        await take_until(provider.events(), is_done)
        items = [event["item"] for event in sent(emulator, "conversation.item.create")]
        assert [(item["role"], item["content"][0]) for item in items] == [
            ("user", {"type": "input_text", "text": "hi robot"}),
            ("assistant", {"type": "output_text", "text": "hello human"}),
            ("user", {"type": "input_text", "text": "and now?"}),
        ]

    history = (HistoryTurn(Role.USER, "hi robot"), HistoryTurn(Role.ASSISTANT, "hello human"))
    run(body, setup=SessionSetup("x", history=history))


def test_image_turn_sends_input_image_deletes_old_frames_and_counts_image_tokens() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        await provider.send_image(TINY_JPEG)
        await provider.send_image(TINY_JPEG)
        await provider.send_text("what do you see?")
        got = await take_until(provider.events(), is_done)
        images = [
            event["item"]
            for event in sent(emulator, "conversation.item.create")
            if event["item"]["content"][0]["type"] == "input_image"
        ]
        assert len(images) == 2
        assert images[0]["content"][0]["image_url"].startswith("data:image/jpeg;base64,")
        assert images[0]["content"][0]["detail"] == "low"
        assert [event["item_id"] for event in sent(emulator, "conversation.item.delete")] == [images[0]["id"]]
        done = got[-1]
        assert isinstance(done, ResponseDone)
        assert done.usage.input_image_tokens == 111  # one frame left in context, at the scripted price
        assert not [e for e in got if isinstance(e, ProviderError)]

    run(body, Script(image_tokens=111))


def test_send_image_refuses_what_is_not_a_jpeg() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        with pytest.raises(ValueError):
            await provider.send_image(b"\x89PNG\r\n")
        assert not sent(emulator, "conversation.item.create")

    run(body)


def test_tool_call_round_trip_even_when_the_result_comes_before_response_done() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        events = provider.events()
        await provider.send_text("wave please")
        got = await take_until(events, lambda event: isinstance(event, ToolCall))
        call = got[-1]
        assert isinstance(call, ToolCall)
        assert (call.name, json.loads(call.arguments)) == ("robot_command", {"command": "wave"})
        await provider.send_tool_results(
            [ToolResult(call.call_id, '{"accepted": true}')]
        )  # the reply is still running
        got = await take_until(events, lambda e: isinstance(e, AssistantTranscript) and e.final)
        assert got[-1].text == "I waved."  # type: ignore[union-attr]
        got += await take_until(events, is_done)
        outputs = [event["item"] for event in sent(emulator, "conversation.item.create")][1:]
        assert outputs == [
            {"type": "function_call_output", "call_id": call.call_id, "output": '{"accepted": true}'}
        ]
        assert not [e for e in got if isinstance(e, ProviderError)]
        tools = sent(emulator, "session.update")[0]["session"]["tools"]
        assert tools == [
            {"type": "function", "name": "robot_command", "description": "move", "parameters": {}}
        ]

    script = Script(turns=(Turn(CallTool("robot_command", '{"command": "wave"}', Say("I waved."))),))
    run(body, script, SessionSetup("x", tools=(ToolSpec("robot_command", "move", {}),)))


def test_the_results_of_several_calls_go_first_then_one_request_for_a_reply() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        events = provider.events()
        await provider.send_text("wave twice")
        got = await take_until(events, is_done)  # the calling response ended
        [call] = [event for event in got if isinstance(event, ToolCall)]
        creates_before = len(sent(emulator, "response.create"))
        await provider.send_tool_results(
            [ToolResult(call.call_id, '{"accepted": true}'), ToolResult(call.call_id, '{"accepted": true}')]
        )
        await take_until(events, lambda e: isinstance(e, AssistantTranscript) and e.final)
        kinds = [record.event["type"] for record in emulator.received][-3:]
        assert kinds == ["conversation.item.create", "conversation.item.create", "response.create"]
        assert len(sent(emulator, "response.create")) == creates_before + 1

    script = Script(turns=(Turn(CallTool("robot_command", '{"command": "wave"}', Say("I waved."))),))
    run(body, script, SessionSetup("x", tools=(ToolSpec("robot_command", "move", {}),)))


def test_a_reply_asked_for_while_one_runs_is_created_when_that_one_is_done() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        events = provider.events()
        await provider.send_text("first")  # answered by silence: that reply runs until cancelled
        await provider.send_text("second")  # one reply at a time: this one has to wait
        await provider.interrupt("", "", played_ms=0)  # cancel whatever runs
        got = await take_until(events, is_done)
        got += await take_until(events, is_done)
        statuses = [e.status for e in got if isinstance(e, ResponseDone)]
        assert statuses == [ResponseStatus.CANCELLED, ResponseStatus.COMPLETED]
        assert [e.text for e in got if isinstance(e, AssistantTranscript) and e.final] == ["Second answer."]
        assert len(sent(emulator, "response.create")) == 2
        assert not [e for e in got if isinstance(e, ProviderError)]

    run(body, Script(turns=(Turn(Silence()), Turn(Say("Second answer.")))))


def test_interrupt_cancels_and_truncates_clamped_to_the_audio_received() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        events = provider.events()
        await provider.send_text("tell me a story")
        got = await take_until(events, lambda e: isinstance(e, AssistantAudio))
        received = sum(len(e.pcm) for e in got if isinstance(e, AssistantAudio))
        first = got[-1]
        assert isinstance(first, AssistantAudio)
        while received < 300 * 48:  # the model stalls after 300 ms: wait for all it sends
            more = await take_until(events, lambda e: isinstance(e, AssistantAudio))
            received += sum(len(e.pcm) for e in more if isinstance(e, AssistantAudio))
        await provider.interrupt(first.response_id, first.item_id, played_ms=5000)  # more than it got
        got = await take_until(events, is_done)
        assert [event["response_id"] for event in sent(emulator, "response.cancel")] == [first.response_id]
        truncate = sent(emulator, "conversation.item.truncate")
        assert [(t["item_id"], t["audio_end_ms"]) for t in truncate] == [(first.item_id, received // 48)]
        done = got[-1]
        assert isinstance(done, ResponseDone) and done.status is ResponseStatus.CANCELLED
        await provider.send_text("still there?")  # the session survived the truncation
        got += await take_until(events, is_done)
        assert not [e for e in got if isinstance(e, ProviderError)]

    long_reply = Turn(Say("Once upon a time there was a robot who loved to talk."), stall_after_ms=300)
    run(body, Script(turns=(long_reply,)))


def test_interrupt_with_nothing_played_sends_no_truncate() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        events = provider.events()
        await provider.send_text("hi")
        first = (await take_until(events, lambda e: isinstance(e, AssistantAudio)))[-1]
        assert isinstance(first, AssistantAudio)
        await provider.interrupt(first.response_id, first.item_id, played_ms=0)
        await take_until(events, is_done)
        assert len(sent(emulator, "response.cancel")) == 1
        assert not sent(emulator, "conversation.item.truncate")

    run(body, Script(turns=(Turn(Say("A long answer."), stall_after_ms=100),)))


def test_cancel_after_the_reply_ended_is_harmless() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        events = provider.events()
        await provider.send_text("hi")
        got = await take_until(events, is_done)
        audio = next(e for e in got if isinstance(e, AssistantAudio))
        await provider.interrupt(audio.response_id, audio.item_id, played_ms=200)
        await provider.send_text("again")
        got = await take_until(events, is_done)
        assert sent(emulator, "response.cancel") and sent(emulator, "conversation.item.truncate")
        assert not [e for e in got if isinstance(e, ProviderError)]  # response_cancel_not_active: dropped
        assert isinstance(got[-1], ResponseDone) and got[-1].status is ResponseStatus.COMPLETED

    run(body)


def test_short_utterance_is_reported_not_committed() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        await provider.send_audio(speech(50))
        await provider.end_of_turn()
        got = await take_until(provider.events(), lambda e: isinstance(e, ProviderError))
        error = got[-1]
        assert isinstance(error, ProviderError) and error.code == "input_audio_buffer_commit_empty"
        assert not error.fatal and error.refuses_turn  # no reply will come: the runtime fails the turn
        assert not sent(emulator, "input_audio_buffer.commit") and not sent(emulator, "response.create")

    run(body)


def test_session_expiry_becomes_session_ending_then_the_events_end() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        got = [event async for event in provider.events()]
        assert [type(event) for event in got] == [SessionEnding]
        with pytest.raises(ProviderClosed):
            await provider.send_text("hello?")

    run(body, Script(session_expiry_s=0.2))


def test_connection_dropped_mid_reply_ends_the_reply_and_the_events() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        await provider.send_text("talk")
        got = [event async for event in provider.events()]
        assert any(isinstance(e, AssistantAudio) for e in got)
        done = got[-1]
        assert isinstance(done, ResponseDone) and done.status is ResponseStatus.FAILED
        assert done.reason.startswith("connection lost: ") and "no close frame" in done.reason
        with pytest.raises(ProviderClosed):
            await provider.send_audio(speech(20))

    run(body, Script(turns=(Turn(Say("This answer never finishes."), drop_after_ms=200),)))


def test_unknown_model_is_a_fatal_error() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        await provider.send_text("hi")
        got = await take_until(provider.events(), is_done)
        errors = [e for e in got if isinstance(e, ProviderError)]
        assert [(e.code, e.fatal) for e in errors] == [("model_not_found", True)]
        assert isinstance(got[-1], ResponseDone) and got[-1].status is ResponseStatus.FAILED

    run(body, Script(known_models=("gpt-realtime-2.1",)), model="gpt-realtime-9")


def test_never_answering_model_leaves_the_deadline_to_the_runtime_and_cancel_ends_it() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        events = provider.events()
        await provider.send_text("hi")
        await provider.interrupt("", "", played_ms=0)  # the runtime's deadline: no id known yet
        done = (await take_until(events, is_done))[-1]
        assert isinstance(done, ResponseDone) and done.status is ResponseStatus.CANCELLED
        assert [event.get("response_id") for event in sent(emulator, "response.cancel")] == [None]

    run(body, Script(turns=(Turn(Silence()),)))


# ---- connection failures (no session to run a body in) ------------------------------------------


def connect_only(script: Script, config: OpenAIRealtimeConfig, api_key: str | None = "sk-test") -> Exception:
    async def main() -> Exception:
        emulator = await start(script=script)
        provider = OpenAIRealtimeProvider(
            replace(config, websocket_base_url=emulator.websocket_base_url), api_key
        )
        try:
            await provider.connect(SETUP)
        except Exception as error:
            return error
        finally:
            await provider.close()
            await emulator.stop()
        raise AssertionError("connect succeeded")

    return asyncio.run(asyncio.wait_for(main(), 30))


def test_bad_key_is_one_fatal_error_that_never_shows_the_key(caplog: pytest.LogCaptureFixture) -> None:
    key = "sk-proj-secret-abcdef123456"
    caplog.set_level(logging.DEBUG)
    error = connect_only(Script(rejected_api_keys=(key,)), OpenAIRealtimeConfig(), api_key=key)
    assert isinstance(error, ProviderFailure)
    assert error.error.fatal and error.error.code == "invalid_api_key"
    assert "OPENAI_API_KEY" in error.error.message
    for text in [str(error), error.error.message, caplog.text]:
        assert key not in text and key[-6:] not in text


def test_beta_shape_rejected_by_the_server_is_fatal() -> None:
    config = OpenAIRealtimeConfig(extra_headers=(("OpenAI-Beta", "realtime=v1"),))  # e.g. a proxy adds it
    error = connect_only(Script(), config)
    assert isinstance(error, ProviderFailure)
    assert error.error.fatal and error.error.code == "beta_api_shape_disabled"


def test_missing_key_is_fatal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    error = connect_only(Script(), OpenAIRealtimeConfig(), api_key=None)
    assert isinstance(error, ProviderFailure) and error.error.fatal


def test_the_sdks_own_openai_base_url_selects_the_endpoint(monkeypatch: pytest.MonkeyPatch) -> None:
    async def main() -> None:
        emulator = await start()
        monkeypatch.setenv("OPENAI_BASE_URL", emulator.base_url)
        monkeypatch.setenv("OPENAI_API_KEY", "sk-from-env")
        provider = OpenAIRealtimeProvider()
        try:
            await provider.connect(SETUP)
            assert emulator.handshakes[0].path == "/v1/realtime?model=gpt-realtime-2.1"
        finally:
            await provider.close()
            await emulator.stop()

    asyncio.run(asyncio.wait_for(main(), 30))


def test_provider_declares_what_the_runtime_needs() -> None:
    provider = OpenAIRealtimeProvider(OpenAIRealtimeConfig(), api_key="sk-test")
    assert (provider.input_sample_rate, provider.max_session_s) == (24000, 3600.0)


def test_close_returns_even_when_nobody_reads_the_events() -> None:
    async def body(emulator: OpenAIRealtimeEmulator, provider: OpenAIRealtimeProvider) -> None:
        await provider.send_text("talk a lot")  # many audio deltas for a queue of one event
        events = provider.events()
        first = await events.__anext__()  # the reader is running and the queue refills behind it
        assert isinstance(first, AssistantAudio | UserTranscript | AssistantTranscript)
        await provider.close()
        rest = [event async for event in events]  # ends: the end marker found room
        assert len(rest) <= 1

    run(
        body,
        Script(turns=(Turn(Say("A reply long enough to fill any small queue twice over.")),)),
        event_queue_size=1,
    )
