"""The Gemini Live provider through the official google-genai SDK against the local TLS emulator.

Assertions are on our typed events and on the client frames the emulator recorded; never on the
emulator's invented details (token counts, timing, handle strings), only on values the test scripts.
The emulator's certificate is trusted through the provider's `ca_file` (async_client_args), never
through a process-wide SSL_CERT_FILE.
"""

from __future__ import annotations

import asyncio
import base64
import json
import logging
import re
import time
from collections.abc import Callable, Coroutine
from typing import Any

import pytest
from emulated_session import is_done, run_session, take_until

from by_your_command.agents.events import (
    AssistantAudio,
    AssistantText,
    AssistantTranscript,
    Interrupted,
    ProviderError,
    ProviderEvent,
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
from by_your_command.agents.providers.gemini_live.provider import GeminiLiveConfig, GeminiLiveProvider
from by_your_command.agents.providers.gemini_live.resumption import ResumptionHandles
from by_your_command.emulators.gemini_live import GeminiLiveEmulator, start
from by_your_command.emulators.gemini_script import CallTool, Say, Script, Turn

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

SETUP = SessionSetup(instructions="You are a robot.")
CONVERSATION = "conversation-1"
HISTORY = (HistoryTurn(Role.USER, "my name is Ada"), HistoryTurn(Role.ASSISTANT, "Hello Ada."))
TINY_JPEG = bytes.fromhex("ffd8ffe000104a46494600010100000100010000ffd9")
KEY = "test-key-1234567890"
Body = Callable[[GeminiLiveEmulator, GeminiLiveProvider], Coroutine[Any, Any, None]]


def settings(emulator: GeminiLiveEmulator, **config: Any) -> GeminiLiveConfig:
    return GeminiLiveConfig(base_url=emulator.base_url, ca_file=str(emulator.cert_file), **config)


def run(
    body: Body,
    script: Script | None = None,
    setup: SessionSetup = SETUP,
    handles: ResumptionHandles | None = None,
    **config: Any,
) -> None:
    def provider(emulator: GeminiLiveEmulator) -> GeminiLiveProvider:
        return GeminiLiveProvider(settings(emulator, **config), api_key=KEY, resumption=handles)

    run_session(lambda: start(script=script), provider, body, setup)


def camel(value: Any) -> Any:
    """A recorded frame with every key in camelCase (the SDK mixes casings)."""
    if isinstance(value, dict):
        return {re.sub(r"_([a-z])", lambda m: m.group(1).upper(), k): camel(v) for k, v in value.items()}
    if isinstance(value, list):
        return [camel(item) for item in value]
    return value


def realtime(emulator: GeminiLiveEmulator, connection: int = 0) -> list[dict[str, Any]]:
    return [camel(body) for body in emulator.received_of("realtimeInput", connection)]


def kinds(frames: list[dict[str, Any]]) -> list[str]:
    return [next(iter(frame)) for frame in frames]


def setup_frame(emulator: GeminiLiveEmulator, connection: int = 0) -> dict[str, Any]:
    frames = [camel(body) for body in emulator.received_of("setup", connection)]
    assert len(frames) == 1
    frame: dict[str, Any] = frames[0]
    return frame


def blob_bytes(blob: dict[str, Any]) -> bytes:
    data = str(blob["data"]).replace("-", "+").replace("_", "/")
    return base64.b64decode(data + "=" * (-len(data) % 4))


def speech(ms: int) -> bytes:
    return b"\x00\x08\x00\xf8" * (16 * ms // 2)  # 16 kHz int16


async def voice_turn(provider: GeminiLiveProvider, chunks: int = 5) -> list[ProviderEvent]:
    events = provider.events()
    for _ in range(chunks):
        await provider.send_audio(speech(40))
    await provider.end_of_turn()
    return await take_until(events, is_done)


# ---- turns ------------------------------------------------------------------------------------
def test_voice_turn_brackets_audio_with_activity_and_gets_audio_transcripts_and_usage() -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        got = await voice_turn(provider)

        assert emulator.handshakes[0].api_version == "v1beta"
        assert emulator.handshakes[0].key_source == "header"
        setup = setup_frame(emulator)
        assert setup["model"] == "models/gemini-3.8-live"
        assert setup["generationConfig"]["responseModalities"] == ["AUDIO"]
        voice = setup["generationConfig"]["speechConfig"]["voiceConfig"]["prebuiltVoiceConfig"]
        assert voice["voiceName"] == "Kore"
        assert setup["realtimeInputConfig"]["automaticActivityDetection"]["disabled"] is True
        assert "inputAudioTranscription" in setup and "outputAudioTranscription" in setup
        assert "sessionResumption" in setup and "contextWindowCompression" in setup
        assert setup["systemInstruction"]["parts"][0]["text"] == "You are a robot."

        frames = realtime(emulator)
        assert kinds(frames) == ["activityStart"] + ["audio"] * 5 + ["activityEnd"]
        assert {frame["audio"]["mimeType"] for frame in frames[1:6]} == {"audio/pcm;rate=16000"}
        assert blob_bytes(frames[1]["audio"]) == speech(40)

        assert [e.text for e in got if isinstance(e, UserTranscript)] == ["hello robot"]
        audio = [e for e in got if isinstance(e, AssistantAudio)]
        assert audio and {e.sample_rate for e in audio} == {24000}
        assert [e.text for e in got if isinstance(e, AssistantTranscript) and e.final] == [
            "Hi, I am listening."
        ]
        done = got[-1]
        assert isinstance(done, ResponseDone) and done.status is ResponseStatus.COMPLETED
        assert done.response_id == audio[0].response_id
        assert done.usage.output_audio_tokens > 0 and done.usage.input_audio_tokens > 0
        assert not [e for e in got if isinstance(e, ProviderError)]

    run(body, Script(turns=(Turn(Say("Hi, I am listening."), heard="hello robot"),)), voice="Kore")


def test_no_audio_is_sent_outside_an_activity_and_an_empty_turn_is_reported() -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        events = provider.events()
        await provider.end_of_turn()  # nothing was said
        error = await anext(events)
        assert isinstance(error, ProviderError) and error.code == "empty_turn"
        assert error.refuses_turn and not error.fatal  # no reply will come: the runtime fails it now
        await voice_turn(provider, chunks=2)
        await voice_turn(provider, chunks=1)
        assert kinds(realtime(emulator)) == ["activityStart", "audio", "audio", "activityEnd"] + [
            "activityStart",
            "audio",
            "activityEnd",
        ]
        assert emulator.sessions[0].audio_outside_activity_ms == 0

    run(body)


def test_a_turn_of_digital_silence_gets_no_reply_and_ends_failed_at_once() -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        events = provider.events()
        await provider.send_audio(bytes(640))  # 20 ms of zeros: a gated microphone
        await provider.end_of_turn()
        [done] = await take_until(events, is_done)
        assert isinstance(done, ResponseDone) and done.status is ResponseStatus.FAILED
        assert "NEED_MORE_INPUT" in done.reason
        got = await voice_turn(provider)  # the session goes on; no scripted turn was used up
        assert [e.text for e in got if isinstance(e, AssistantTranscript) and e.final] == ["Yes?"]

    run(body, Script(turns=(Turn(Say("Yes?")),)))


def test_text_turn_is_client_content_with_turn_complete() -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        await provider.send_text("what time is it")
        got = await take_until(provider.events(), is_done)
        content = [camel(body) for body in emulator.received_of("clientContent")]
        assert content == [
            {"turns": [{"role": "user", "parts": [{"text": "what time is it"}]}], "turnComplete": True}
        ]
        assert [e.text for e in got if isinstance(e, AssistantTranscript) and e.final] == ["It is noon."]
        assert [e for e in got if isinstance(e, AssistantAudio)]

    run(body, Script(turns=(Turn(Say("It is noon.")),)))


def test_a_context_note_is_client_content_without_turn_complete() -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        await provider.add_context('"stop" (the robot stopped)')
        await provider.send_text("are you there?")
        got = await take_until(provider.events(), is_done)
        content = [camel(body) for body in emulator.received_of("clientContent")]
        note = {"role": "user", "parts": [{"text": '"stop" (the robot stopped)'}]}
        assert content[0] == {"turns": [note], "turnComplete": False}
        assert content[1]["turnComplete"] is True
        assert [e.text for e in got if isinstance(e, AssistantTranscript) and e.final] == ["Yes."]

    run(body, Script(turns=(Turn(Say("Yes.")),)))


@pytest.mark.parametrize("text_replies", ["transcription", "text"])
def test_text_only_agent_gets_text_replies_and_no_audio(text_replies: str) -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        await provider.send_text("wave please")
        got = await take_until(provider.events(), is_done)
        modality = "AUDIO" if text_replies == "transcription" else "TEXT"
        assert setup_frame(emulator)["generationConfig"]["responseModalities"] == [modality]
        assert [e.text for e in got if isinstance(e, AssistantText) and e.final] == ["wave"]
        assert not [e for e in got if isinstance(e, (AssistantAudio, AssistantTranscript))]

    run(
        body,
        Script(turns=(Turn(Say("wave")),)),
        SessionSetup("Answer with commands.", audio_out=False),
        text_replies=text_replies,
    )


@pytest.mark.parametrize("frame_modality", ["IMAGE", "VIDEO"])
def test_image_turn_sends_the_frame_once_as_video_and_counts_image_tokens(frame_modality: str) -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        await provider.send_image(TINY_JPEG)
        got = await voice_turn(provider, chunks=3)
        frames = realtime(emulator)
        videos = [frame["video"] for frame in frames if "video" in frame]
        assert len(videos) == 1, "a frame is sent once, not per audio chunk"
        assert videos[0]["mimeType"] == "image/jpeg" and blob_bytes(videos[0]) == TINY_JPEG
        done = got[-1]
        assert isinstance(done, ResponseDone) and done.usage.input_image_tokens > 0

    run(body, Script(frame_modality=frame_modality))  # type: ignore[arg-type]


def test_history_seeds_a_fresh_session_as_client_content_without_turn_complete() -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        await provider.send_text("and now?")
        await take_until(provider.events(), is_done)
        first = camel(emulator.received_of("clientContent")[0])
        assert first.get("turnComplete") in (None, False)
        assert [(turn["role"], turn["parts"][0]["text"]) for turn in first["turns"]] == [
            ("user", "my name is Ada"),
            ("model", "Hello Ada."),
        ]
        assert provider.resumed is False

    run(body, setup=SessionSetup("You are a robot.", history=HISTORY))


# ---- tools, interruption --------------------------------------------------------------------
def test_tool_call_round_trip_continues_in_a_new_response() -> None:
    tool = ToolSpec(
        "robot_command", "Send a command", {"type": "object", "properties": {"command": {"type": "string"}}}
    )

    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        events = provider.events()
        await provider.send_text("wave")
        first = await take_until(events, is_done)
        calls = [e for e in first if isinstance(e, ToolCall)]
        assert len(calls) == 1 and calls[0].name == "robot_command"
        assert json.loads(calls[0].arguments) == {"command": "wave"}
        assert first[-1].response_id == calls[0].response_id  # the tool-calling response ends there

        await provider.send_tool_results(
            [ToolResult(calls[0].call_id, json.dumps({"accepted": True, "command": "wave"}))]
        )
        second = await take_until(events, is_done)
        assert [e.text for e in second if isinstance(e, AssistantTranscript) and e.final] == ["I waved."]
        assert second[-1].response_id != calls[0].response_id

        declared = setup_frame(emulator)["tools"][0]["functionDeclarations"][0]
        assert declared["name"] == "robot_command" and declared["behavior"] == "BLOCKING"
        response = camel(emulator.received_of("toolResponse")[0])["functionResponses"][0]
        assert response["id"] == calls[0].call_id and response["name"] == "robot_command"
        assert response["response"] == {"accepted": True, "command": "wave"}

    script = Script(turns=(Turn(CallTool("robot_command", '{"command": "wave"}', Say("I waved."))),))
    run(body, script, SessionSetup("You are a robot.", tools=(tool,)))


def test_interrupt_sends_activity_start_and_maps_interrupted() -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        events = provider.events()
        await provider.send_text("tell me a long story")
        first_audio = await take_until(events, lambda e: isinstance(e, AssistantAudio))
        reply = first_audio[-1].response_id  # type: ignore[union-attr]

        await provider.interrupt(reply, reply, played_ms=100)
        cut = await take_until(events, is_done)
        assert Interrupted(reply) in cut
        done = cut[-1]
        assert isinstance(done, ResponseDone) and done.response_id == reply
        assert done.status is ResponseStatus.CANCELLED

        # The user's held audio follows in the activity the interruption opened.
        for _ in range(3):
            await provider.send_audio(speech(40))
        await provider.end_of_turn()
        answer = await take_until(events, is_done)
        assert isinstance(answer[-1], ResponseDone) and answer[-1].status is ResponseStatus.COMPLETED
        assert kinds(realtime(emulator)) == ["activityStart", "audio", "audio", "audio", "activityEnd"]

    script = Script(
        turns=(Turn(Say("Once upon a time there was a robot."), stall_after_ms=200), Turn(Say("Yes?")))
    )
    run(body, script)


# ---- session lifetime -----------------------------------------------------------------------
def test_go_away_becomes_session_ending_with_the_time_left() -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        events = provider.events()
        await provider.send_text("hi")
        got = await take_until(events, lambda e: isinstance(e, SessionEnding))
        ending = got[-1]
        assert isinstance(ending, SessionEnding) and ending.seconds_left == 30.0
        assert provider.max_session_s == 50 * 60.0  # rotated by the runtime before the 58-min close

    run(body, Script(go_away_after_turns=1, go_away_time_left_s=30.0))


def test_a_handle_sent_after_turn_complete_is_not_lost() -> None:
    handles = ResumptionHandles()

    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        await provider.send_text("hi")
        # turnComplete, then the handle, then goAway: only a reader that goes on after receive()
        # ends (at turnComplete) sees the last two.
        await take_until(provider.events(), lambda e: isinstance(e, SessionEnding))
        assert handles.usable(CONVERSATION) == emulator.handles.issued[-1]

    setup = SessionSetup("You are a robot.", conversation_id=CONVERSATION)
    run(body, Script(go_away_after_turns=1, go_away_time_left_s=60.0), setup, handles=handles)


def test_newest_handle_resumes_the_next_connection_with_history_kept() -> None:
    async def main() -> None:
        turns = (Turn(Say("One.")), Turn(Say("Two.")), Turn(Say("Three.")))
        emulator = await start(script=Script(turns, go_away_after_turns=2, go_away_time_left_s=60.0))
        handles = ResumptionHandles()
        first = GeminiLiveProvider(settings(emulator), api_key=KEY, resumption=handles)
        await first.connect(SessionSetup("You are a robot.", conversation_id=CONVERSATION))
        await first.send_text("first")
        await take_until(first.events(), is_done)
        await first.send_text("second")
        # The second turn's handle comes after its turnComplete and before the goAway.
        await take_until(first.events(), lambda e: isinstance(e, SessionEnding))
        newest = handles.usable(CONVERSATION)
        assert newest == emulator.handles.issued[-1]
        await first.close()  # the old socket is closed before resuming

        second = GeminiLiveProvider(settings(emulator), api_key=KEY, resumption=handles)
        await second.connect(SessionSetup("You are a robot.", history=HISTORY, conversation_id=CONVERSATION))
        try:
            await second.send_text("third")
            await take_until(second.events(), is_done)
            assert second.resumed is True
            assert setup_frame(emulator, 1)["sessionResumption"]["handle"] == newest
            content = [camel(body) for body in emulator.received_of("clientContent", 1)]
            assert (
                len(content) == 1 and content[0]["turns"][0]["parts"][0]["text"] == "third"
            )  # no re-seeding
            said = [text for _, text in emulator.sessions[1].conversation.transcript]
            assert said[:4] == ["first", "One.", "second", "Two."]  # the newest handle: both turns kept
        finally:
            await second.close()
            await emulator.stop()

    asyncio.run(asyncio.wait_for(main(), 30))


def test_a_refused_resume_falls_back_to_a_fresh_session_with_text_context() -> None:
    handles = ResumptionHandles()
    handles.keep("stale-handle", CONVERSATION)

    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        assert [closed.code for closed in emulator.closes] == [1007]
        assert setup_frame(emulator, 0)["sessionResumption"]["handle"] == "stale-handle"
        assert "handle" not in setup_frame(emulator, 1)["sessionResumption"]
        assert provider.resumed is False and handles.usable(CONVERSATION) is None
        await provider.send_text("hi")
        await take_until(provider.events(), is_done)  # frames arrive in order: the history came first
        seeded = camel(emulator.received_of("clientContent", 1)[0])
        assert seeded["turns"][0]["parts"][0]["text"] == "my name is Ada"

    setup = SessionSetup("You are a robot.", history=HISTORY, conversation_id=CONVERSATION)
    run(body, Script(refuse_resume=True), setup, handles)


def test_a_session_without_history_never_resumes() -> None:
    handles = ResumptionHandles()
    handles.keep("old-conversation", "")

    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        assert "handle" not in setup_frame(emulator)["sessionResumption"]

    run(body, handles=handles)  # SETUP has no history: nothing to continue


def test_a_session_of_another_conversation_never_resumes_and_the_old_handle_is_dropped() -> None:
    """A reset mid-conversation: the next session carries the new conversation's words as history,
    but resuming the old conversation's handle would bring its server-side state back whole."""

    async def main() -> None:
        emulator = await start(
            script=Script(turns=(Turn(Say("One.")), Turn(Say("Two.")), Turn(Say("Three."))))
        )
        handles = ResumptionHandles()
        try:
            old = GeminiLiveProvider(settings(emulator), api_key=KEY, resumption=handles)
            await old.connect(SessionSetup("You are a robot.", conversation_id="before-reset"))
            await old.send_text("first")
            await take_until(old.events(), is_done)
            await until_handle(handles, "before-reset")
            await old.close()

            new = GeminiLiveProvider(settings(emulator), api_key=KEY, resumption=handles)
            await new.connect(
                SessionSetup("You are a robot.", history=HISTORY, conversation_id="after-reset")
            )
            assert handles.usable("before-reset") is None  # dropped, not kept for later
            await new.send_text("second")
            await take_until(new.events(), is_done)
            await until_handle(handles, "after-reset")
            await new.close()
            assert new.resumed is False
            assert "handle" not in setup_frame(emulator, 1)["sessionResumption"]
            said = [text for _, text in emulator.sessions[1].conversation.transcript]
            assert "first" not in said and said[0] == "my name is Ada"  # fresh, seeded with its own history

            again = GeminiLiveProvider(settings(emulator), api_key=KEY, resumption=handles)
            await again.connect(
                SessionSetup("You are a robot.", history=HISTORY, conversation_id="after-reset")
            )
            await again.close()
            assert again.resumed is True  # the new conversation's own handle is used
        finally:
            await emulator.stop()

    asyncio.run(asyncio.wait_for(main(), 30))


async def until_handle(handles: ResumptionHandles, conversation_id: str) -> None:
    """The handle comes after turnComplete: wait for it (a condition, never a fixed time)."""
    deadline = time.monotonic() + 20.0
    while handles.usable(conversation_id) is None:
        if time.monotonic() > deadline:
            raise AssertionError(f"no resumption handle for {conversation_id}")
        await asyncio.sleep(0.01)


def test_deadline_close_mid_reply_ends_the_reply_and_the_session() -> None:
    async def body(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        got = [event async for event in provider.events()]
        errors_ = [e for e in got if isinstance(e, ProviderError)]
        assert errors_ and errors_[0].code == "server_closed" and not errors_[0].fatal
        assert "1011" in errors_[0].message
        failed = [e for e in got if isinstance(e, ResponseDone)]
        assert failed and failed[-1].status is ResponseStatus.FAILED
        assert failed[-1].reason == errors_[0].message  # the turn's report names the 1011
        with pytest.raises(ProviderClosed):
            await provider.send_audio(speech(40))

    async def start_turn(emulator: GeminiLiveEmulator, provider: GeminiLiveProvider) -> None:
        await provider.send_text("tell me a story")
        await body(emulator, provider)

    run(start_turn, Script(turns=(Turn(Say("Once upon a time there was a robot."), close_after_ms=200),)))


# ---- refusals -------------------------------------------------------------------------------
def refused(script: Script, api_key: str | None = KEY, **config: Any) -> ProviderFailure:
    async def main() -> ProviderFailure:
        emulator = await start(script=script)
        provider = GeminiLiveProvider(settings(emulator, **config), api_key=api_key)
        try:
            with pytest.raises(ProviderFailure) as raised:
                await provider.connect(SETUP)
            return raised.value
        finally:
            await provider.close()
            await emulator.stop()

    return asyncio.run(asyncio.wait_for(main(), 30))


def test_a_rejected_key_is_fatal_with_one_clear_message_and_never_logged(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.DEBUG)
    failure = refused(Script(rejected_api_keys=(KEY,)))
    assert failure.error.fatal and failure.error.code == "invalid_api_key"
    assert "GEMINI_API_KEY" in failure.error.message
    assert KEY not in str(failure) and KEY not in caplog.text


def test_a_missing_key_is_fatal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("GEMINI_API_KEY", raising=False)
    monkeypatch.delenv("GOOGLE_API_KEY", raising=False)
    failure = refused(Script(), api_key=None)
    assert failure.error.fatal and failure.error.code == "missing_api_key"


def test_an_unknown_model_is_fatal() -> None:
    failure = refused(Script(known_models=("gemini-3.8-live",)), model="gemini-0-nonexistent")
    assert failure.error.fatal and failure.error.code == "model_not_found"


def test_an_untrusted_certificate_is_fatal_and_names_ca_file() -> None:
    async def main() -> ProviderFailure:
        emulator = await start()
        other = await start()  # its certificate does not sign the first emulator's
        provider = GeminiLiveProvider(
            GeminiLiveConfig(base_url=emulator.base_url, ca_file=str(other.cert_file)), api_key=KEY
        )
        try:
            with pytest.raises(ProviderFailure) as raised:
                await provider.connect(SETUP)
            return raised.value
        finally:
            await provider.close()
            await emulator.stop()
            await other.stop()

    failure = asyncio.run(asyncio.wait_for(main(), 30))
    assert failure.error.fatal and "ca_file" in failure.error.message


def test_the_sdk_environment_variables_set_the_endpoint(monkeypatch: pytest.MonkeyPatch) -> None:
    async def main() -> None:
        emulator = await start()
        monkeypatch.setenv("GOOGLE_GEMINI_BASE_URL", emulator.base_url)
        monkeypatch.setenv("GOOGLE_GENAI_API_VERSION", "v1alpha")
        monkeypatch.setenv("GEMINI_API_KEY", KEY)
        monkeypatch.delenv("GOOGLE_API_KEY", raising=False)
        provider = GeminiLiveProvider(GeminiLiveConfig(ca_file=str(emulator.cert_file)))
        try:
            await provider.connect(SETUP)
            assert emulator.handshakes[0].api_version == "v1alpha"
            assert emulator.handshakes[0].key_source == "header"
        finally:
            await provider.close()
            await emulator.stop()

    asyncio.run(asyncio.wait_for(main(), 30))


def test_config_is_validated() -> None:
    with pytest.raises(ValueError):
        GeminiLiveConfig(model="")
    with pytest.raises(ValueError):
        GeminiLiveConfig(text_replies="speech")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        GeminiLiveConfig(ping_timeout_s=0)


def test_tool_schemas_keep_only_the_keywords_gemini_documents() -> None:
    from by_your_command.agents.providers.gemini_live.provider import _gemini_schema

    # "contentEncoding" as a property is a field's name (kept); inside a field, a keyword (dropped)
    schema = {
        "type": "object",
        "properties": {
            "contentEncoding": {"type": "string", "contentEncoding": "base64", "maxLength": 8},
            "pose": {"type": "object", "properties": {"x": {"type": "number"}}, "$comment": "x"},
        },
        "required": ["pose"],
        "additionalProperties": False,
    }
    assert _gemini_schema(schema) == {
        "type": "object",
        "properties": {
            "contentEncoding": {"type": "string", "maxLength": 8},
            "pose": {"type": "object", "properties": {"x": {"type": "number"}}},
        },
        "required": ["pose"],
        "additionalProperties": False,
    }
