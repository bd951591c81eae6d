"""The GPT-Live provider: its event translator on the SDK's own server event models (time given,
no waiting), then the provider through the official SDK against the local emulator (loopback).

Assertions are on our typed events and on what the emulator recorded the client sending; never on
the emulator's invented details (timing, ids), except values the test itself scripts.
"""

from __future__ import annotations

import asyncio
import base64
import json
from collections.abc import Callable, Coroutine
from typing import Any

import numpy as np
import pytest
from emulated_session import is_done, run_session, sent, take_until
from openai.types.live import (
    DelegationCreatedEvent,
    ErrorEvent,
    InputTranscriptDeltaEvent,
    OutputAudioDeltaEvent,
    OutputTranscriptDeltaEvent,
    SessionClosedEvent,
    SessionResource,
    SessionUsage,
    SessionUsageUpdatedEvent,
)
from openai.types.live.delegation_created_event import Delegation
from openai.types.live.error import Error

from by_your_command.agents.app_config import ProviderChoice, load_app_config
from by_your_command.agents.app_providers import build_provider
from by_your_command.agents.config import AgentConfigError, EchoMode
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
    Usage,
    UsageReport,
    UserTranscript,
)
from by_your_command.agents.provider import (
    HistoryTurn,
    ProviderClosed,
    ProviderFailure,
    Role,
    SessionSetup,
    ToolResult,
)
from by_your_command.agents.providers.gpt_live.config import GptLiveConfig
from by_your_command.agents.providers.gpt_live.errors import handshake_error, provider_error
from by_your_command.agents.providers.gpt_live.events import (
    LiveTranslator,
    UnknownEvent,
    UnreadableEvent,
    parse_server_event,
)
from by_your_command.agents.providers.gpt_live.input import InputClock, SilencePlan
from by_your_command.agents.providers.gpt_live.provider import GptLiveProvider
from by_your_command.emulators.gpt_live import GptLiveEmulator, start
from by_your_command.emulators.gpt_live_script import Delegate, Say, Script, Turn

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

GAP = 0.5  # the translator's reply_end_gap_s in the unit tests
PCM = b"\x01\x00" * 240


# ---- the translator, on SDK-built server events -----------------------------------------------


def audio(pcm: bytes = PCM) -> OutputAudioDeltaEvent:
    return OutputAudioDeltaEvent(type="session.output_audio.delta", delta=base64.b64encode(pcm).decode())


def said(text: str) -> OutputTranscriptDeltaEvent:
    return OutputTranscriptDeltaEvent(
        type="session.output_transcript.delta", event_id="e", delta=text, start_ms=0, end_ms=1
    )


def heard(text: str) -> InputTranscriptDeltaEvent:
    return InputTranscriptDeltaEvent(
        type="session.input_transcript.delta", event_id="e", delta=text, start_ms=0, end_ms=1
    )


def delegation(delegation_id: str, target: Any = "client") -> DelegationCreatedEvent:
    return DelegationCreatedEvent(
        type="session.delegation.created",
        event_id="e",
        offset_ms=0,
        delegation=Delegation(id=delegation_id, target=target, type="delegation"),
    )


def session_resource() -> SessionResource:
    return SessionResource(id="sess_1", expires_at=0, model="gpt-live-1", status="active")


def translator(**options: Any) -> LiveTranslator:
    return LiveTranslator(24_000, GAP, "robot_command", **options)


def feed(live: LiveTranslator, *timed: tuple[float, Any]) -> list[ProviderEvent]:
    out: list[ProviderEvent] = []
    for now, event in timed:
        out += live.translate(event, now)
    return out


def test_a_reply_is_the_output_until_it_goes_quiet_for_the_gap() -> None:
    live = translator()
    out = feed(live, (0.0, heard("hello")), (0.1, heard(" robot")), (1.0, audio()), (1.1, said("Hi")))
    assert isinstance(out[0], UserTranscript) and out[0].text == "hello robot"  # before the answer
    sound, words = out[1], out[2]
    assert isinstance(sound, AssistantAudio) and sound.pcm == PCM and sound.sample_rate == 24_000
    assert isinstance(words, AssistantTranscript) and (words.text, words.final) == ("Hi", False)
    assert words.response_id == sound.response_id
    out += feed(live, (1.3, said(" there")), (1.4, audio()))
    assert live.deadline() == pytest.approx(1.4 + GAP)
    assert live.tick(1.4 + GAP - 0.01) == []  # still within the gap: the same reply
    end = live.tick(1.4 + GAP)
    assert end == [
        AssistantTranscript(sound.response_id, sound.item_id, "Hi there", final=True),
        ResponseDone(sound.response_id, ResponseStatus.COMPLETED),
    ]
    assert live.deadline() is None
    (next_sound,) = feed(live, (3.0, audio()))
    assert isinstance(next_sound, AssistantAudio) and next_sound.response_id != sound.response_id


def test_the_user_transcript_is_one_event_per_utterance() -> None:
    live = translator()
    feed(live, (0.0, heard("are")), (0.1, heard(" you there")))
    (transcript,) = live.tick(0.1 + GAP)
    assert isinstance(transcript, UserTranscript) and transcript.text == "are you there"
    assert live.tick(1.0 + GAP) == []


def test_a_client_delegation_is_a_tool_call_with_the_words_since_the_last_one() -> None:
    live = translator()
    out = feed(
        live, (0.0, heard("please")), (0.1, heard(" wave")), (0.5, delegation("dlg_1")), (0.6, audio())
    )
    assert isinstance(out[0], UserTranscript)
    call = out[1]
    assert isinstance(call, ToolCall)
    assert (call.call_id, call.name, json.loads(call.arguments)) == (
        "dlg_1",
        "robot_command",
        {"command": "please wave"},
    )
    assert isinstance(out[2], AssistantAudio) and out[2].response_id == call.response_id  # "one moment"
    assert isinstance(live.tick(0.6 + GAP)[-1], ResponseDone)
    (_, second) = feed(live, (2.0, heard("now   nod\n")), (2.5, delegation("dlg_2")))
    assert isinstance(second, ToolCall) and json.loads(second.arguments) == {"command": "now nod"}
    live.tick(2.5 + GAP)
    feed(live, (4.0, heard("hello")), (4.5, audio()))  # answered by speech: not a task
    live.tick(4.5 + GAP)
    feed(live, (6.0, heard("turn")), (6.5, said("Sure.")), (6.6, heard(" left")))  # the user adds to it
    (third,) = feed(live, (6.7, delegation("dlg_3")))
    assert isinstance(third, ToolCall) and json.loads(third.arguments) == {"command": "turn left"}
    assert feed(live, (7.0, delegation("dlg_4", target="responses"))) == []  # not ours to run
    assert live.ignored["delegation:responses"] == 1


def test_a_reply_that_stops_after_the_user_began_speaking_yielded_to_the_user() -> None:
    live = translator()
    (sound,) = feed(live, (0.0, audio()))
    assert isinstance(sound, AssistantAudio)
    live.user_speech(0.3, starts=True)
    feed(live, (0.4, audio()))  # the model needs a moment to hear it
    assert live.tick(0.4 + GAP) == [
        Interrupted(sound.response_id),
        ResponseDone(sound.response_id, ResponseStatus.CANCELLED, reason="the model yielded to the user"),
    ]


def test_a_model_that_yields_before_its_next_delta_is_still_seen_to_yield() -> None:
    """The user began after the last delta arrived (its audio still sounding) and the model sent
    nothing more: a yield, ended by the short gap, not a completed reply its answer would join."""
    live = translator(yield_gap_s=0.1)
    (sound,) = feed(live, (0.0, audio()), (1.0, audio()))[:1]
    assert isinstance(sound, AssistantAudio)
    live.user_speech(1.05, starts=True)
    assert live.deadline() == pytest.approx(1.1)
    interrupted, done = live.tick(1.1)
    assert interrupted == Interrupted(sound.response_id)
    assert isinstance(done, ResponseDone) and done.status is ResponseStatus.CANCELLED
    (answer,) = feed(live, (1.5, audio()))
    assert isinstance(answer, AssistantAudio) and answer.response_id != sound.response_id


def test_a_reply_to_speech_that_ended_before_it_completes() -> None:
    live = translator()
    live.user_speech(0.0, starts=True)
    live.user_speech(0.2, starts=False)
    (sound,) = feed(live, (1.0, audio()))
    assert isinstance(sound, AssistantAudio)
    assert live.tick(1.0 + GAP) == [ResponseDone(sound.response_id, ResponseStatus.COMPLETED)]


def test_a_reply_the_runtime_cut_plays_no_more_and_ends_cancelled() -> None:
    live = translator()
    (sound,) = feed(live, (0.0, audio()))
    assert isinstance(sound, AssistantAudio)
    live.cut(sound.response_id)
    assert feed(live, (0.1, audio())) == []  # the model may talk on: not played
    assert live.tick(0.1 + GAP) == [
        ResponseDone(sound.response_id, ResponseStatus.CANCELLED, reason="cut by the user")
    ]


def test_text_replies_for_a_command_agent() -> None:
    live = translator(text_replies=True)
    out = feed(live, (0.0, audio()), (0.0, said("pan@left")))
    assert len(out) == 1 and isinstance(out[0], AssistantText) and not out[0].final
    final, done = live.tick(GAP)
    assert isinstance(final, AssistantText) and (final.text, final.final) == ("pan@left", True)
    assert isinstance(done, ResponseDone)


def test_usage_is_a_running_total_reported_by_its_increases() -> None:
    live = translator()
    reports = []
    for seconds in (3.0, 5.0, 4.0, float("nan")):  # totals, not increments; a smaller one is no news
        usage = SessionUsageUpdatedEvent(
            type="session.usage.updated", event_id="e", usage=SessionUsage(seconds=seconds)
        )
        reports += live.translate(usage, 0.0)
    assert reports == [UsageReport(Usage(session_s=3.0)), UsageReport(Usage(session_s=2.0))]
    assert live.billed_seconds == 5.0

    def closed(reason: Any, seconds: float = 61.0) -> SessionClosedEvent:
        return SessionClosedEvent(
            type="session.closed",
            event_id="e",
            reason=reason,
            session=session_resource(),
            usage=SessionUsage(seconds=seconds),
        )

    final, ending = live.translate(closed("expired"), 0.0)
    assert final == UsageReport(Usage(session_s=56.0)) and isinstance(ending, SessionEnding)
    (error,) = live.translate(closed("content"), 0.0)
    assert isinstance(error, ProviderError) and not error.fatal
    assert live.translate(closed("close_requested"), 0.0) == []
    assert live.billed_seconds == 61.0


def test_a_reply_the_user_spoke_over_is_ended_by_the_short_yield_gap() -> None:
    live = translator(yield_gap_s=0.1)
    (sound,) = feed(live, (0.0, audio()))
    assert isinstance(sound, AssistantAudio)
    assert live.deadline() == pytest.approx(GAP)  # nobody spoke over it: the reply-end gap
    live.user_speech(0.3, starts=True)
    feed(live, (0.4, audio()))
    assert live.deadline() == pytest.approx(0.5)  # spoken over: quiet this long means it yielded
    assert live.tick(0.45) == []
    interrupted, done = live.tick(0.5)
    assert interrupted == Interrupted(sound.response_id)
    assert isinstance(done, ResponseDone) and done.status is ResponseStatus.CANCELLED


def test_the_input_clock_fills_silence_between_utterances_at_real_time() -> None:
    clock = InputClock(1000, max_catch_up_s=0.5)
    assert clock.silence_due(1.0) == SilencePlan(0, 0)  # not started
    clock.start(1.0)
    assert clock.silence_due(1.1) == SilencePlan(100, 0)
    clock.in_utterance = True
    clock.speech_sent(1.3)
    assert clock.silence_due(1.5) == SilencePlan(0, 0)  # never spliced into speech
    clock.speech_sent(1.6)  # the last chunk: said by the time it came
    clock.in_utterance = False
    assert clock.silence_due(1.65) == SilencePlan(50, 0)  # silence from there on, no gap, no overlap
    assert clock.silence_due(1.65) == SilencePlan(0, 0)
    assert clock.silence_due(4.65) == SilencePlan(500, 2500)  # a stall: no 3 s burst, the clock moves on
    assert clock.silence_due(4.75) == SilencePlan(100, 0)


def test_errors_are_typed_and_never_quote_the_key() -> None:
    refused = ErrorEvent(
        type="error",
        event_id="e",
        error=Error(code="invalid_api_key", message="Incorrect API key provided: sk-ab***yz", type="x"),
    )
    (error,) = translator().translate(refused, 0.0)
    assert isinstance(error, ProviderError) and error.fatal and "sk-ab" not in error.message
    assert provider_error("model_not_found", "no such model").fatal
    limited = provider_error("rate_limit_exceeded", "Please try again in 250ms.")
    assert not limited.fatal and limited.retry_after_s == pytest.approx(0.25)
    assert not provider_error("invalid_value", "No client delegation with id 'x'.").fatal
    assert handshake_error(401).fatal and handshake_error(404).fatal
    assert handshake_error(429, "inf").retry_after_s == 600.0
    assert handshake_error(429, "2").retry_after_s == 2.0
    assert not handshake_error(503).fatal


def test_frames_are_validated_and_unknown_events_counted() -> None:
    with pytest.raises(UnreadableEvent):
        parse_server_event(b"not json")
    with pytest.raises(UnreadableEvent):
        parse_server_event(json.dumps({"type": "session.output_audio.delta", "delta": 7}))
    with pytest.raises(UnreadableEvent):
        parse_server_event(json.dumps([1, 2]))
    parsed = parse_server_event(json.dumps({"type": "response.event", "event": {}, "event_id": "e"}))
    assert parsed == UnknownEvent("response.event")
    live = translator()
    assert live.translate(parsed, 0.0) == []
    assert live.ignored["response.event"] == 1
    bad = OutputAudioDeltaEvent(type="session.output_audio.delta", delta="%%%")
    (error,) = live.translate(bad, 0.0)
    assert isinstance(error, ProviderError) and error.code == "invalid_server_event"


def test_a_lost_connection_fails_the_reply_in_flight() -> None:
    live = translator()
    (sound,) = feed(live, (0.0, audio()))
    assert isinstance(sound, AssistantAudio)
    feed(live, (0.1, heard("wait")))
    out = live.connection_lost("connection lost: 1006")
    assert isinstance(out[0], UserTranscript) and out[0].text == "wait"
    assert out[1] == ResponseDone(sound.response_id, ResponseStatus.FAILED, reason="connection lost: 1006")


def test_the_provider_kind_is_registered_with_its_settings_checked() -> None:
    choice = ProviderChoice("gpt_live", "", {"voice": "cedar", "sample_rate": 16000})
    built = build_provider(choice, {"OPENAI_API_KEY": "sk-test"})
    provider = built.factory()
    assert isinstance(provider, GptLiveProvider) and provider.input_sample_rate == 16000
    assert built.settings["model"] == "gpt-live-1" and built.secret == "sk-test"
    with pytest.raises(AgentConfigError, match="OPENAI_API_KEY is not set"):
        build_provider(choice, {})
    with pytest.raises(AgentConfigError, match="sample_rate"):
        build_provider(ProviderChoice("gpt_live", "", {"sample_rate": 44100}), {"OPENAI_API_KEY": "k"})
    with pytest.raises(AgentConfigError, match="credentials"):
        build_provider(
            ProviderChoice("gpt_live", "", {"extra_headers": {"Authorization": "x"}}), {"OPENAI_API_KEY": "k"}
        )


def test_the_shipped_config_is_valid_and_keeps_the_camera_off() -> None:
    app = load_app_config("agent_gpt_live.yaml")
    assert app.provider.type == "gpt_live" and app.agent.topics.camera == ""  # GPT-Live takes no images
    provider = build_provider(app.provider, {"OPENAI_API_KEY": "sk-test"}).factory()
    assert isinstance(provider, GptLiveProvider) and provider.config == GptLiveConfig()
    assert app.agent.echo_mode is EchoMode.AEC and provider.duplex


def test_a_gated_microphone_is_refused_for_a_full_duplex_model() -> None:
    with pytest.raises(AgentConfigError, match="echo_mode: gpt_live is full duplex.*not gate"):
        load_app_config("agent_gpt_live.yaml", ["echo_mode=gate"])
    assert load_app_config("agent_gpt_live.yaml", ["echo_mode=external"]).agent.echo_mode is EchoMode.EXTERNAL
    assert load_app_config("agent_openai.yaml", ["echo_mode=gate"]).agent.echo_mode is EchoMode.GATE


# ---- the provider against the emulator ---------------------------------------------------------

SETUP = SessionSetup(
    instructions="You are a robot.",
    history=(HistoryTurn(Role.USER, "hi"), HistoryTurn(Role.ASSISTANT, "hello"), HistoryTurn(Role.USER, " ")),
)
Body = Callable[[GptLiveEmulator, GptLiveProvider], Coroutine[Any, Any, None]]


def run(body: Body, script: Script, setup: SessionSetup = SETUP, **config: Any) -> None:
    def provider(emulator: GptLiveEmulator) -> GptLiveProvider:
        settings = GptLiveConfig(
            websocket_base_url=emulator.websocket_base_url, reply_end_gap_ms=150, **config
        )
        return GptLiveProvider(settings, api_key="sk-test")

    run_session(lambda: start(script=script), provider, body, setup)


def speech(ms: int = 400, rate: int = 24_000) -> bytes:
    t = np.arange(rate * ms // 1000) / rate
    return (8000 * np.sin(2 * np.pi * 220 * t)).astype("<i2").tobytes()


def final_words(events: list[ProviderEvent]) -> list[str]:
    return [e.text for e in events if isinstance(e, AssistantTranscript) and e.final]


def test_a_spoken_turn_is_answered_with_audio_transcripts_and_an_end() -> None:
    script = Script(turns=(Turn(Say("Hi there"), heard="hello robot"),), pace=0)

    async def body(emulator: GptLiveEmulator, provider: GptLiveProvider) -> None:
        (start_event,) = sent(emulator, "session.start")
        session = start_event["session"]
        assert session["model"] == "gpt-live-1" and session["delegation"] == {"type": "client"}
        assert session["audio"] == {
            "format": {"type": "audio/pcm", "rate": 24000},
            "output": {"voice": "marin"},
        }
        assert session["instructions"] == "You are a robot."
        assert [(item["role"], item["content"][0]["text"]) for item in session["input"]] == [
            ("user", "hi"),
            ("assistant", "hello"),
        ]
        await provider.send_audio(speech())
        await provider.end_of_turn()  # the silence that lets the model hear the user stop
        events = await take_until(provider.events(), is_done)
        transcripts = [e for e in events if isinstance(e, UserTranscript)]
        assert [t.text for t in transcripts] == ["hello robot"]
        sounds = [e for e in events if isinstance(e, AssistantAudio)]
        assert sounds and {s.sample_rate for s in sounds} == {24_000}
        assert final_words(events) == ["Hi there"]
        done = events[-1]
        assert isinstance(done, ResponseDone) and done.status is ResponseStatus.COMPLETED
        assert {s.response_id for s in sounds} == {done.response_id}
        with pytest.raises(ValueError, match="no images"):
            await provider.send_image(b"\xff\xd8\xff\xd9")
        await provider.add_context("The robot stopped.")
        await provider.mute()
        await provider.unmute()
        await provider.close()  # waits for session.closed: the server has read everything before it
        (context,) = sent(emulator, "session.instructions.append")
        assert context["content"] == "The robot stopped." and context["delegation_id"] is None
        assert emulator.received_types()[-3:] == [
            "session.input_audio.mute",
            "session.input_audio.unmute",
            "session.close",
        ]

    run(body, script)


def test_a_delegation_is_a_tool_call_whose_result_the_model_speaks() -> None:
    script = Script(turns=(Turn(Delegate(Say("One moment."), Say("I waved.")), heard="please wave"),), pace=0)

    async def body(emulator: GptLiveEmulator, provider: GptLiveProvider) -> None:
        await provider.send_audio(speech())
        await provider.end_of_turn()
        events = await take_until(provider.events(), is_done)
        (call,) = [e for e in events if isinstance(e, ToolCall)]
        assert call.name == "robot_command" and json.loads(call.arguments) == {"command": "please wave"}
        assert final_words(events) == ["One moment."]
        await provider.send_tool_progress(call.call_id, "moving the arm")
        await provider.send_tool_results([ToolResult(call.call_id, '{"accepted": true}')])
        follow_up = await take_until(provider.events(), is_done)
        assert final_words(follow_up) == ["I waved."]
        (thinking,) = sent(emulator, "session.thinking.append")
        assert thinking["delegation_id"] == call.call_id
        (commentary,) = sent(emulator, "session.commentary.append")
        assert commentary["delegation_id"] == call.call_id and '{"accepted": true}' in commentary["content"]

    run(body, script)


def test_silence_follows_each_utterance_at_real_time() -> None:
    script = Script(turns=(Turn(Say("Hi"), heard="hello"),), pace=0)

    async def body(emulator: GptLiveEmulator, provider: GptLiveProvider) -> None:
        started = asyncio.get_running_loop().time() - 0.05  # the silence began at the connect, just before
        await provider.send_audio(speech(400))
        await provider.end_of_turn()  # no silence appended here: it follows at the clock's pace
        await take_until(provider.events(), is_done)  # the model heard the user stop
        elapsed = asyncio.get_running_loop().time() - started
        appended = sum(
            len(base64.b64decode(event["audio"])) // 2
            for event in sent(emulator, "session.input_audio.append")
        )
        # Silence covers the time after the speech at real time: never more than has passed.
        assert appended <= 24_000 * (elapsed + 0.4)
        assert appended > 24_000 * 0.4  # speech, then silence

    run(body, script, input_tick_ms=20)


def test_speech_over_a_reply_makes_the_model_yield() -> None:
    script = Script(turns=(Turn(Say("A long story " * 20), heard="tell me a story"),), pace=0.2)

    async def body(emulator: GptLiveEmulator, provider: GptLiveProvider) -> None:
        await provider.send_audio(speech())
        await provider.end_of_turn()
        await take_until(provider.events(), lambda e: isinstance(e, AssistantAudio))
        await provider.send_audio(speech())  # the user talks over it: the model decides to stop
        events = await take_until(provider.events(), is_done)
        (interrupted,) = [e for e in events if isinstance(e, Interrupted)]
        done = events[-1]
        assert isinstance(done, ResponseDone) and done.status is ResponseStatus.CANCELLED
        assert done.response_id == interrupted.response_id
        assert emulator.interruptions

    run(body, script)


def test_close_waits_for_the_server_to_confirm_the_end() -> None:
    async def main() -> None:
        emulator = await start(script=Script())
        settings = GptLiveConfig(websocket_base_url=emulator.websocket_base_url)
        provider = GptLiveProvider(settings, api_key="sk-test")
        try:
            await provider.connect(SessionSetup(instructions=""))
            await provider.close()
            assert "session.close" in emulator.received_types()
            assert provider.finalized  # close waited for session.closed
            assert [e async for e in provider.events()] == []
            with pytest.raises(ProviderClosed):
                await provider.send_audio(b"\x00\x00")
            await provider.close()  # twice is harmless
        finally:
            await emulator.stop()

    asyncio.run(asyncio.wait_for(main(), 30))


@pytest.mark.parametrize(
    ("script", "config", "code"),
    [
        (Script(rejected_api_keys=("sk-revoked",)), {}, "invalid_api_key"),
        (Script(known_models=("gpt-live-1",)), {"model": "gpt-live-nope"}, "model_not_found"),
    ],
)
def test_a_bad_key_or_unknown_model_is_a_fatal_failure(
    script: Script, config: dict[str, Any], code: str, caplog: pytest.LogCaptureFixture
) -> None:
    async def main() -> None:
        emulator = await start(script=script)
        settings = GptLiveConfig(websocket_base_url=emulator.websocket_base_url, **config)
        provider = GptLiveProvider(settings, api_key="sk-revoked")
        try:
            with pytest.raises(ProviderFailure) as failure:
                await provider.connect(SETUP)
            assert failure.value.error.fatal and failure.value.error.code == code
            assert "sk-revoked" not in str(failure.value)
        finally:
            await provider.close()
            await emulator.stop()

    caplog.set_level("DEBUG")
    asyncio.run(asyncio.wait_for(main(), 30))
    assert "sk-revoked" not in caplog.text
