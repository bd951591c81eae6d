"""The offline provider with the real engine (pocketsphinx, espeak-ng) on speech espeak-ng makes.

A few utterances only, synthesized once per module into tmp: recognition accuracy is measured in
bench/, these tests check what the provider does with what it hears. The last test runs the real
AgentRuntime on virtual time (with worker threads waited for, see ThreadAwareLoop) and checks the
command reaches response_cmd and the verdict is spoken.
"""

from __future__ import annotations

import asyncio
import json
import logging
import selectors
import subprocess
from collections import Counter
from collections.abc import Callable, Coroutine, Sequence
from datetime import datetime
from typing import Any, TypeVar

import pytest
import yaml
from fake_port import FakePort
from virtual_time import Deadlock, VirtualClock, VirtualTimeLoop

from by_your_command.agents.config import AgentConfig, AgentRole
from by_your_command.agents.events import (
    AssistantAudio,
    AssistantText,
    AssistantTranscript,
    ProviderError,
    ProviderEvent,
    ResponseDone,
    ResponseStatus,
    ToolCall,
    Usage,
    UserTranscript,
)
from by_your_command.agents.inputs import UtteranceChunk
from by_your_command.agents.provider import ProviderClosed, SessionSetup, ToolResult, ToolSpec
from by_your_command.agents.providers.local import engine as local_engine
from by_your_command.agents.providers.local.config import OfflineConfig
from by_your_command.agents.providers.local.engine import LocalEngine
from by_your_command.agents.providers.local.provider import OfflineProvider
from by_your_command.agents.robot_calls import call_result
from by_your_command.agents.robot_tool import ROBOT_COMMAND_TOOL, TOOL_NAME, result_json
from by_your_command.agents.runtime import LATE_RESULT_NOTE, AgentRuntime
from by_your_command.audio.pcm import read_wav, resample
from by_your_command.cli import byc
from by_your_command.local_speech.recognizer import Recognition
from by_your_command.local_speech.speaker import Speaker
from by_your_command.local_speech.tool_phrases import ToolPhrase

pytestmark = pytest.mark.unit
T = TypeVar("T")
RATE = 16000
TOOLS = SessionSetup("offline test", tools=(ROBOT_COMMAND_TOOL,))
UTTERANCES = {
    "follow": "follow me",
    "time": "what time is it",
    "chat": "my grandmother baked a lovely cake for the neighbours yesterday",
    "kitchen": "go to the kitchen",
    "kitchen chat": "the kitchen is nice",
    "boat": "I docked my boat",
}
# The robot's own tools, as the runtime offers them from the catalog (agents/tool_calls.robot_tool_spec).
GO_TO = ToolSpec(
    "go_to",
    "Drive to a named place.",
    {"type": "object", "properties": {"place": {"type": "string", "enum": ["kitchen", "charging dock"]}}},
    long_running=True,
    spoken=tuple(
        (f"{verb} to the {place}", json.dumps({"place": place}))
        for place in ("kitchen", "charging dock")
        for verb in ("go", "drive")
    ),
)
DOCK = ToolSpec(
    "dock", "Dock.", {"type": "object", "properties": {}}, long_running=True, spoken=(("dock", "{}"),)
)
STATUS = ToolSpec(
    "status",
    "Report the status.",
    {"type": "object", "properties": {}},
    spoken=(("report your status", "{}"),),
)
ROBOT_TOOLS = SessionSetup("offline test", tools=(ROBOT_COMMAND_TOOL, GO_TO, DOCK, STATUS))
REPLY_TIMEOUT_S = 120.0  # real time, 2 shared cores: only a hung engine ever gets near it


# --- fixtures ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def engine() -> LocalEngine:
    """One engine for the module: loading the recognizer is the slow part."""
    shared = LocalEngine(OfflineConfig())
    shared.load()
    return shared


@pytest.fixture(scope="module")
def speech(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """Each utterance as 16 kHz PCM16 with a little silence around it, as the VAD hands it over
    (150 words per minute, the rate the engine's own tests and bench use)."""
    folder = tmp_path_factory.mktemp("speech")
    spoken = {}
    pad = bytes(int(0.3 * RATE) * 2)
    for name, text in UTTERANCES.items():
        path = folder / f"{name}.wav"
        subprocess.run(
            ["espeak-ng", "-v", "en-us", "-s", "150", "-w", str(path), text], check=True, timeout=60
        )
        pcm, rate, _ = read_wav(path)
        spoken[name] = pad + resample(pcm, rate, RATE).tobytes() + pad
    return spoken


class SpyEngine:
    """The real engine, recording how much audio each decode was given."""

    def __init__(self, inner: LocalEngine) -> None:
        self.inner = inner
        self.decoded_bytes: list[int] = []

    def load(self) -> None:
        self.inner.load()

    def recognize(self, pcm: bytes, sample_rate: int) -> Recognition:
        self.decoded_bytes.append(len(pcm))
        return self.inner.recognize(pcm, sample_rate)

    def understand(self, text: str) -> Recognition:
        return self.inner.understand(text)

    def say(self, text: str) -> tuple[bytes, int]:
        return self.inner.say(text)

    def use_tools(self, phrases: Sequence[ToolPhrase]) -> Counter[str]:
        return self.inner.use_tools(phrases)


# --- helpers -----------------------------------------------------------------------------------


def run(coroutine: Coroutine[Any, Any, T]) -> T:
    return asyncio.run(asyncio.wait_for(coroutine, REPLY_TIMEOUT_S))


async def until_done(provider: OfflineProvider, replies: int = 1) -> list[ProviderEvent]:
    """Events up to and including the `replies`-th ResponseDone."""
    events: list[ProviderEvent] = []
    stream = provider.events()
    async for event in stream:
        events.append(event)
        if isinstance(event, ResponseDone):
            replies -= 1
            if replies == 0:
                break
    return events


async def say_turn(provider: OfflineProvider, pcm: bytes, chunk_bytes: int = 3200) -> None:
    for start in range(0, len(pcm), chunk_bytes):
        await provider.send_audio(pcm[start : start + chunk_bytes])
    await provider.end_of_turn()


def of(events: list[ProviderEvent], kind: type[T]) -> list[T]:
    return [event for event in events if isinstance(event, kind)]


def spoken_text(events: list[ProviderEvent]) -> str:
    [transcript] = of(events, AssistantTranscript)
    assert transcript.final
    return transcript.text


def audio_of(events: list[ProviderEvent]) -> bytes:
    chunks = of(events, AssistantAudio)
    assert chunks and {chunk.sample_rate for chunk in chunks} == {chunks[0].sample_rate}
    return b"".join(chunk.pcm for chunk in chunks)


def at_7_past_3() -> datetime:
    return datetime(2030, 5, 4, 15, 7)


# --- the shipped config --------------------------------------------------------------------------


def test_the_offline_config_is_valid_without_any_key(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    for name in ("OPENAI_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY", "BYC_BRIDGE_URL"):
        monkeypatch.delenv(name, raising=False)
    assert byc.main(["agent", "--config", "agent_offline.yaml", "--check"]) == 0
    effective = yaml.safe_load(capsys.readouterr().out)
    assert (effective["role"], effective["echo_mode"]) == ("tools", "gate")
    assert effective["provider"]["type"] == "offline"
    assert effective["provider"]["not_heard_text"] == "I did not catch that."
    # Settings are checked like every provider's: named in the message, exit code 2.
    for setting, named in [
        ("provider.words_per_minute=5000", "words_per_minute"),
        ("provider.refusal_text='No {why}'", "refusal_text"),
        ("provider.model=gpt-realtime-2.1", "provider.model: unknown key"),
    ]:
        assert byc.main(["agent", "--config", "agent_offline.yaml", "--set", setting, "--check"]) == 2
        assert named in capsys.readouterr().err


# --- the provider alone ------------------------------------------------------------------------


def test_a_spoken_command_is_a_tool_call_and_the_accepted_verdict_is_acknowledged(
    engine: LocalEngine, speech: dict[str, bytes]
) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(TOOLS)
        await say_turn(provider, speech["follow"])
        events = await until_done(provider)
        assert [type(event) for event in events] == [UserTranscript, ToolCall, ResponseDone]
        [heard] = of(events, UserTranscript)
        assert heard.text == "follow me"
        [call] = of(events, ToolCall)
        assert call.name == TOOL_NAME and json.loads(call.arguments) == {"command": "follow@me"}
        assert events[-1] == ResponseDone(call.response_id, ResponseStatus.COMPLETED)

        await provider.send_tool_results(
            [ToolResult(call.call_id, result_json(True, "follow@me", "behavior command"))]
        )
        reply = await until_done(provider)
        assert spoken_text(reply) == "Following you."
        rate = of(reply, AssistantAudio)[0].sample_rate
        assert len(audio_of(reply)) > 0.3 * rate * 2  # at least 0.3 s of speech
        done = reply[-1]
        assert isinstance(done, ResponseDone) and done.status is ResponseStatus.COMPLETED
        assert done.usage == Usage() and done.response_id != call.response_id
        assert of(reply, ToolCall) == []
        await provider.close()

    run(scenario())


def test_a_refused_command_speaks_the_refusal(engine: LocalEngine) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(TOOLS)
        await provider.send_text("Reach, please!")
        [call] = of(await until_done(provider), ToolCall)
        assert json.loads(call.arguments) == {"command": "reach"}
        await provider.send_tool_results(
            [ToolResult(call.call_id, result_json(False, "reach", "'reach' is not allowed"))]
        )
        reply = await until_done(provider)
        assert spoken_text(reply) == "I can't do that: 'reach' is not allowed."
        assert audio_of(reply)
        # A verdict nobody can read is a refusal too, and says so.
        await provider.send_tool_results([ToolResult(call.call_id, "{not json")])
        assert (
            spoken_text(await until_done(provider)) == "I can't do that: the robot's answer was unreadable."
        )
        await provider.close()

    run(scenario())


def test_a_spoken_question_gets_a_spoken_answer(engine: LocalEngine, speech: dict[str, bytes]) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine, now=at_7_past_3)
        await provider.connect(TOOLS)
        await say_turn(provider, speech["time"])
        events = await until_done(provider)
        assert of(events, ToolCall) == []
        assert spoken_text(events) == "It is 3 07 PM."
        assert audio_of(events)
        assert provider.stats.answers == 1
        await provider.close()

    run(scenario())


def test_chat_is_never_a_command_and_is_not_caught(engine: LocalEngine, speech: dict[str, bytes]) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(TOOLS)
        await say_turn(provider, speech["chat"])
        events = await until_done(provider)
        assert of(events, ToolCall) == []
        assert spoken_text(events) == "I did not catch that."
        assert provider.stats.not_caught == 1 and provider.stats.commands == 0
        # The decoder's guess at chat is filler words: it never enters the shared transcript.
        assert [heard.text for heard in of(events, UserTranscript)] == [""]
        await provider.close()

        quiet = OfflineProvider(OfflineConfig(not_heard_text=""), engine)  # switched off: says nothing
        await quiet.connect(TOOLS)
        await say_turn(quiet, speech["chat"])
        events = await until_done(quiet)
        assert of(events, ToolCall) == [] and of(events, AssistantAudio) == []
        assert of(events, AssistantTranscript) == []
        await quiet.close()

    run(scenario())


def test_not_caught_is_left_unsaid_when_the_user_already_speaks_again(
    engine: LocalEngine, speech: dict[str, bytes]
) -> None:
    """A late "I did not catch that" talked over the next command and, half duplex, cut it to its
    first 0.45 s: when the next utterance has begun by the time the chat line is decoded, nothing
    is said, and the command is heard whole."""

    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(TOOLS)
        await say_turn(provider, speech["chat"])
        # The runtime streams the next utterance as it is said, before the chat line is decoded.
        follow = speech["follow"]
        half = len(follow) // 4 * 2  # whole samples
        await provider.send_audio(follow[:half])
        events = await until_done(provider)
        assert of(events, ToolCall) == [] and of(events, AssistantAudio) == []
        assert of(events, AssistantTranscript) == []
        assert provider.stats.not_caught == 1 and provider.stats.not_caught_unsaid == 1
        await say_turn(provider, follow[half:])
        [call] = of(await until_done(provider), ToolCall)
        assert json.loads(call.arguments) == {"command": "follow@me"}
        await provider.close()

    run(scenario())


def test_the_not_heard_reply_is_made_when_the_engine_loads(
    engine: LocalEngine, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Said to every chat line, the not-heard reply costs no synthesis when it is needed."""
    monkeypatch.setattr(local_engine, "OfflineRecognizer", lambda config: engine._recognizer)
    synthesized: list[str] = []
    synthesize = Speaker.say

    def counted(speaker: Speaker, text: str) -> tuple[bytes, int]:
        synthesized.append(text)
        return synthesize(speaker, text)

    monkeypatch.setattr(Speaker, "say", counted)
    fresh = LocalEngine(OfflineConfig(not_heard_text="Sorry, say again?"))
    fresh.load()
    assert synthesized == ["Sorry, say again?"]
    pcm, rate = fresh.say("Sorry, say again?")
    assert len(pcm) > 0.3 * rate * 2 and synthesized == ["Sorry, say again?"]  # not made again


def test_text_turns_use_the_same_meanings_without_the_recognizer(engine: LocalEngine) -> None:
    async def scenario() -> None:
        spy = SpyEngine(engine)
        provider = OfflineProvider(OfflineConfig(max_text_chars=40), spy)
        await provider.connect(TOOLS)
        await provider.send_text("please turn to the left")
        await provider.send_text("wake up")  # a wake phrase is the wake command of the processor
        await provider.send_text("who are you")
        await provider.send_text("hello there, how was your day")
        await provider.send_text("look up " * 10)  # over max_text_chars: not matched at all
        events = await until_done(provider, replies=5)
        assert [json.loads(call.arguments)["command"] for call in of(events, ToolCall)] == [
            "turn@left",
            "wake",
        ]
        assert [t.text for t in of(events, AssistantTranscript)] == [
            "I am Barney, a robot. I am running offline, so I only understand simple commands.",
            "I did not catch that.",
            "I did not catch that.",
        ]
        assert of(events, UserTranscript) == []  # the runtime already knows what was typed
        assert spy.decoded_bytes == []
        assert provider.stats.text_turns == 5 and provider.stats.oversize_texts == 1
        await provider.close()

    run(scenario())


def test_a_command_agent_gets_the_command_as_text_and_nothing_else(engine: LocalEngine) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(SessionSetup("command agent", audio_out=False))
        await provider.send_text("follow me")
        await provider.send_text("what time is it")
        events = await until_done(provider, replies=2)
        assert [text.text for text in of(events, AssistantText)] == ["follow@me"]
        assert of(events, AssistantAudio) == [] and of(events, AssistantTranscript) == []
        await provider.close()

    run(scenario())


def test_oversize_audio_is_cut_to_the_limit_and_counted(
    engine: LocalEngine, speech: dict[str, bytes]
) -> None:
    async def scenario() -> None:
        spy = SpyEngine(engine)
        provider = OfflineProvider(OfflineConfig(max_turn_s=2.0), spy)
        await provider.connect(TOOLS)
        limit = 2 * RATE * 2
        hour = 3600 * RATE * 2
        await provider.send_audio(speech["follow"][: limit // 2])
        await provider.send_audio(bytes(hour))  # an hour of audio in one turn: dropped, not buffered
        await provider.end_of_turn()
        events = await until_done(provider)
        [error] = of(events, ProviderError)
        assert error.code == "audio_truncated" and not error.fatal
        assert spy.decoded_bytes == [limit]
        assert provider.stats.dropped_audio_bytes == limit // 2 + hour - limit
        assert provider.stats.truncated_turns == 1
        with pytest.raises(ValueError):
            await provider.send_audio(b"\x00\x01\x02")  # not whole samples
        await provider.close()
        with pytest.raises(ProviderClosed):
            await provider.send_audio(bytes(2))

    run(scenario())


def test_an_interrupt_stops_the_reply_audio(engine: LocalEngine) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(audio_chunk_ms=20), engine)
        await provider.connect(TOOLS)
        await provider.send_text("what can you do")  # the longest answer: several seconds of audio
        stream = provider.events()
        first = await anext(stream)
        assert isinstance(first, AssistantAudio)
        await provider.interrupt(first.response_id, first.item_id, played_ms=20)
        rest: list[ProviderEvent] = []
        async for event in stream:
            rest.append(event)
            if isinstance(event, ResponseDone):
                break
        assert of(rest, AssistantAudio) == []
        assert rest[-1] == ResponseDone(first.response_id, ResponseStatus.CANCELLED)
        assert provider.stats.interrupted == 1
        # The next reply is heard in full.
        await provider.send_text("who are you")
        after = await until_done(provider)
        assert audio_of(after) and after[-1].status is ResponseStatus.COMPLETED  # type: ignore[union-attr]
        await provider.close()

    run(scenario())


# --- the robot's own tools (docs/offline.md) ------------------------------------------------------


async def call_of(provider: OfflineProvider, text: str) -> ToolCall:
    """The tool call a typed turn makes (its reply is the call and done, nothing said)."""
    await provider.send_text(text)
    events = await until_done(provider)
    assert [type(event) for event in events] == [ToolCall, ResponseDone], events
    [call] = of(events, ToolCall)
    return call


async def reply_to(provider: OfflineProvider, call_id: str, output: str) -> str:
    await provider.send_tool_results([ToolResult(call_id, output)])
    return spoken_text(await until_done(provider))


def test_a_spoken_tool_phrase_is_that_tools_call_and_its_success_is_acknowledged(
    engine: LocalEngine, speech: dict[str, bytes]
) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(ROBOT_TOOLS)
        await say_turn(provider, speech["kitchen"])
        events = await until_done(provider)
        assert [type(event) for event in events] == [UserTranscript, ToolCall, ResponseDone]
        assert of(events, UserTranscript)[0].text == "go to the kitchen"
        [call] = of(events, ToolCall)
        assert (call.name, json.loads(call.arguments)) == ("go_to", {"place": "kitchen"})
        assert call.response_id == events[-1].response_id
        said = await reply_to(provider, call.call_id, call_result("go_to", True, "succeeded", {}))
        assert said == "Done."
        assert provider.stats.tool_calls == 1 and provider.stats.commands == 0
        await provider.close()

    run(scenario())


def test_chat_with_a_tools_words_is_not_caught(engine: LocalEngine, speech: dict[str, bytes]) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(ROBOT_TOOLS)
        for name in ("kitchen chat", "boat"):
            await say_turn(provider, speech[name])
            events = await until_done(provider)
            assert of(events, ToolCall) == [], name
            assert spoken_text(events) == "I did not catch that."
        for text in ("the kitchen is nice", "I docked my boat", "go to the kitchen and make tea", "kitchen"):
            await provider.send_text(text)
            events = await until_done(provider)
            assert of(events, ToolCall) == [] and spoken_text(events) == "I did not catch that.", text
        assert provider.stats.not_caught == 6 and provider.stats.tool_calls == 0
        await provider.close()

    run(scenario())


def test_typed_tool_phrases_are_calls_and_each_result_is_said_plainly(engine: LocalEngine) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(ROBOT_TOOLS)
        call = await call_of(provider, "Please drive to the charging dock!")
        assert (call.name, json.loads(call.arguments)) == ("go_to", {"place": "charging dock"})
        failed = call_result(
            "go_to", False, "failed", error="the robot reported failure: the path is blocked"
        )
        assert await reply_to(provider, call.call_id, failed) == (
            "I can't do that: the robot reported failure: the path is blocked."
        )
        # A service's own message is its reply (bounded, speakable); without one, "Done.".
        call = await call_of(provider, "report your status")
        assert call.name == "status" and json.loads(call.arguments) == {}
        message = {"success": True, "message": "Battery at 80 percent <speak>" + "x" * 500}
        said = await reply_to(provider, call.call_id, call_result("status", True, "succeeded", message))
        assert said.startswith("Battery at 80 percent speak") and len(said) <= 161 and "<" not in said
        call = await call_of(provider, "dock")
        # Never dressed as success: only an explicit ok is one.
        for output in (
            json.dumps({"ok": "yes", "tool": "dock", "status": "succeeded"}),
            call_result("dock", False, "cancelled", error=""),
            json.dumps({"ok": False, "error": ["not", "text"]}),
        ):
            said = await reply_to(provider, call.call_id, output)
            assert said.startswith("I can't do that:") and "Done" not in said, output
        await provider.close()

    run(scenario())


def test_a_late_result_is_answered_when_it_comes_after_other_turns(engine: LocalEngine) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine, now=at_7_past_3)
        await provider.connect(ROBOT_TOOLS)
        going = await call_of(provider, "go to the kitchen")
        await provider.send_text("what time is it")
        assert spoken_text(await until_done(provider)) == "It is 3 07 PM."
        look = await call_of(provider, "look up")
        assert await reply_to(provider, look.call_id, result_json(True, "lookup", "")) == "Looking up."
        await provider.send_tool_progress(going.call_id, "go_to in progress: distance_remaining 2.5")
        await provider.send_tool_progress(going.call_id, "go_to in progress: distance_remaining 0.4")
        assert provider.stats.tool_progress == 2  # nothing is said of progress
        done = call_result("go_to", True, "succeeded", {"result": {}})
        assert await reply_to(provider, going.call_id, done) == "Done."
        assert provider._calls == {}  # every call answered: nothing left open
        await provider.close()

    run(scenario())


def test_an_earlier_sessions_result_is_answered_from_the_runtimes_note(engine: LocalEngine) -> None:
    """A robot action that ends after its session did reaches the next session as a note (a text
    turn): it is answered like a result, not as chat."""

    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(ROBOT_TOOLS)
        for output, said in [
            (call_result("go_to", True, "succeeded", {}), "Done."),
            (
                call_result("go_to", False, "cancelled", error="cancelled: stop"),
                "I can't do that: cancelled: stop.",
            ),
        ]:
            await provider.send_text(
                LATE_RESULT_NOTE.format(tool="go_to", arguments='{"place": "kitchen"}', result=output)
            )
            assert spoken_text(await until_done(provider)) == said
        await provider.close()

    run(scenario())


def test_open_calls_are_remembered_within_a_bound_and_a_forgotten_ones_result_still_answered(
    engine: LocalEngine,
) -> None:
    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(), engine)
        await provider.connect(ROBOT_TOOLS)
        first = await call_of(provider, "look up")
        for _ in range(64):  # never answered: the runtime would, this bound is for when it does not
            await call_of(provider, "dock")
        assert len(provider._calls) == 64 and provider.stats.calls_forgotten == 1
        # The oldest was forgotten: its result is answered from the result alone.
        assert await reply_to(provider, first.call_id, result_json(True, "lookup", "")) == "Done."
        await provider.close()

    run(scenario())


def test_the_recognizer_is_rebuilt_only_when_the_phrases_change(engine: LocalEngine) -> None:
    async def scenario() -> None:
        first = OfflineProvider(OfflineConfig(), engine)
        await first.connect(ROBOT_TOOLS)
        rebuilds = engine.rebuilds
        same = OfflineProvider(OfflineConfig(), engine)  # a new session, the same tools: no rebuild
        await same.connect(SessionSetup("again", tools=(DOCK, STATUS, GO_TO, ROBOT_COMMAND_TOOL)))
        assert engine.rebuilds == rebuilds
        plain = OfflineProvider(OfflineConfig(), engine)  # robot_command only: no tool phrase heard
        await plain.connect(TOOLS)
        assert engine.rebuilds == rebuilds + 1
        await plain.send_text("go to the kitchen")
        assert spoken_text(await until_done(plain)) == "I did not catch that."
        third = OfflineProvider(OfflineConfig(), engine)
        await third.connect(ROBOT_TOOLS)  # the engine hears go_to again ...
        await plain.send_text("go to the kitchen")  # ... which this session was not given
        assert spoken_text(await until_done(plain)) == "I did not catch that."
        assert plain.stats.unknown_tools == 1 and plain.stats.tool_calls == 0
        for provider in (first, same, plain, third):
            await provider.close()

    run(scenario())


def test_tool_phrases_beyond_the_limits_are_left_out_and_counted(
    engine: LocalEngine, caplog: pytest.LogCaptureFixture
) -> None:
    many = ToolSpec(
        "fetch",
        "Fetch a thing.",
        {"type": "object"},
        spoken=(
            ("fetch the red box", '{"thing": "red box"}'),
            ("fetch the blue box", '{"thing": "blue box"}'),
            ("fetch the qwzx", '{"thing": "qwzx"}'),  # no pronunciation: left out by the recognizer
            ("fetch the green box", '{"thing": "green box"}'),  # beyond max_tool_phrases
            ("fetch the big old heavy red wooden box with the lid", "{}"),  # beyond max_tool_phrase_words
        ),
    )

    async def scenario() -> None:
        provider = OfflineProvider(OfflineConfig(max_tool_phrases=3, max_tool_phrase_words=6), engine)
        with caplog.at_level(logging.WARNING):
            await provider.connect(SessionSetup("limits", tools=(ROBOT_COMMAND_TOOL, many)))
        assert provider.stats.tool_phrases_left_out == 3
        assert "fetch the qwzx" in caplog.text and "fetch the green box" in caplog.text
        call = await call_of(provider, "fetch the blue box")
        assert json.loads(call.arguments) == {"thing": "blue box"}
        for text in ("fetch the green box", "fetch the qwzx"):
            await provider.send_text(text)
            assert spoken_text(await until_done(provider)) == "I did not catch that."
        await provider.close()

    run(scenario())


# --- with the real AgentRuntime ----------------------------------------------------------------


class _ThreadAwareSelector(selectors.DefaultSelector):
    """Virtual time that stands still while a worker thread runs: the clock only jumps when every
    task waits on a timer and no thread can still wake the loop (decoding takes no virtual time)."""

    def __init__(self, loop: ThreadAwareLoop) -> None:
        super().__init__()
        self._loop = loop

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        if self._loop.busy_threads and timeout != 0:
            ready = super().select(REPLY_TIMEOUT_S)  # the thread's result arrives through the self-pipe
            if not ready:
                raise Deadlock(f"a worker thread ran for more than {REPLY_TIMEOUT_S} s")
            return ready
        ready = super().select(0)
        if ready:
            return ready
        if timeout is None:
            raise Deadlock("every task is waiting and no timer is scheduled")
        self._loop.advance(timeout)
        return []


class ThreadAwareLoop(VirtualTimeLoop):
    def __init__(self) -> None:
        self._now = 0.0
        self.busy_threads = 0
        asyncio.SelectorEventLoop.__init__(self, _ThreadAwareSelector(self))

    def run_in_executor(self, executor: Any, func: Callable[..., T], *args: Any) -> asyncio.Future[T]:
        future = super().run_in_executor(executor, func, *args)
        self.busy_threads += 1
        future.add_done_callback(self._thread_done)
        return future

    def _thread_done(self, _: object) -> None:
        self.busy_threads -= 1


async def wait_until(condition: Callable[[], bool], virtual_s: float = 60.0) -> None:
    for _ in range(int(virtual_s * 10)):
        if condition():
            return
        await asyncio.sleep(0.1)
    raise AssertionError("condition not reached in virtual time")


def test_the_runtime_publishes_a_spoken_command_and_speaks_the_verdict(
    engine: LocalEngine, speech: dict[str, bytes]
) -> None:
    async def scenario() -> None:
        config = AgentConfig(role=AgentRole.TOOLS, pause_timeout_s=60.0)
        port = FakePort()
        runtime = AgentRuntime(
            config, "offline", port, lambda: OfflineProvider(OfflineConfig(), engine), VirtualClock()
        )
        task = asyncio.create_task(runtime.run())
        pcm = speech["follow"]
        chunk = 3200  # 100 ms, the VAD's pace
        pieces = [pcm[start : start + chunk] for start in range(0, len(pcm), chunk)]
        for sequence, piece in enumerate(pieces):
            port.push(UtteranceChunk(piece, RATE, 1, sequence, sequence == len(pieces) - 1))
            await asyncio.sleep(0.1)
        await wait_until(lambda: port.requests() == ["follow@me"])
        port.push(port.verdict(0, reason="behavior command"))
        await wait_until(lambda: "Following you." in port.of("text"))
        await wait_until(lambda: any(chunk.end_of_stream for chunk in port.voice()))
        assert port.voice() and all(chunk.pcm or chunk.end_of_stream for chunk in port.voice())
        assert [turn.outcome for turn in port.turns()] == ["completed"]
        assert port.of("transcript") == ["follow me"]
        port.close()
        await asyncio.wait_for(task, 30)

    loop = ThreadAwareLoop()
    try:
        loop.run_until_complete(asyncio.wait_for(scenario(), 600))
    finally:
        loop.run_until_complete(loop.shutdown_asyncgens())
        loop.close()
