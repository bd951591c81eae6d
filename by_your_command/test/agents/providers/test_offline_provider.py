"""The offline provider with the real engine (pocketsphinx, espeak-ng) on speech espeak-ng makes.

A few utterances only, synthesized once per module into tmp: recognition accuracy is measured in
bench/, these tests check what the provider does with what it hears. The last test runs the real
AgentRuntime on virtual time (with worker threads waited for, see ThreadAwareLoop) and checks the
command reaches response_cmd and the verdict is spoken.
"""

from __future__ import annotations

import asyncio
import json
import selectors
import subprocess
from collections.abc import Callable, Coroutine
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
from by_your_command.agents.provider import ProviderClosed, SessionSetup, ToolResult
from by_your_command.agents.providers import offline_engine
from by_your_command.agents.providers.offline import OfflineProvider
from by_your_command.agents.providers.offline_config import OfflineConfig
from by_your_command.agents.providers.offline_engine import LocalEngine
from by_your_command.agents.robot_tool import ROBOT_COMMAND_TOOL, TOOL_NAME, result_json
from by_your_command.agents.runtime import AgentRuntime
from by_your_command.audio.pcm import read_wav, resample
from by_your_command.cli import byc
from by_your_command.offline.recognizer import Recognition
from by_your_command.offline.speaker import Speaker

pytestmark = pytest.mark.unit
T = TypeVar("T")
RATE = 16000
TOOLS = SessionSetup("offline test", tools=(ROBOT_COMMAND_TOOL,))
UTTERANCES = {
    "follow": "follow me",
    "time": "what time is it",
    "chat": "my grandmother baked a lovely cake for the neighbours yesterday",
}
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
    monkeypatch.setattr(offline_engine, "OfflineRecognizer", lambda config: engine._recognizer)
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
