"""The offline provider: no network, no key, no model. It hears commands, answers a few questions,
and says "I did not catch that" to everything else (nothing, when the user already speaks again).

A turn's audio is buffered (bounded) and decoded at end_of_turn by the offline recognizer
(by_your_command/local_speech/: pocketsphinx with a language model generated from the command
vocabulary and a garbage loop, so chat is rejected, not forced into a command); typed text is
matched against the same spoken forms. A command becomes a `robot_command` tool call
(tool mode), so the runtime publishes it on `response_cmd` and hands back the command processor's
verdict; the reply to that verdict is spoken with espeak-ng: an acknowledgement or the refusal.

The robot's other tools are heard by their declared phrases (ToolSpec.spoken: "go to the kitchen"
-> go_to {"place": "kitchen"}), which the recognizer takes as forms judged like commands, so chat
with a tool's words in it is still not caught. A phrase heard becomes that tool's call; its result
(replies.py) is answered when it comes, however many turns later for an action: "Done.",
the service's own message, or the failure said plainly as a refusal, never as a success.

The runtime's session model is kept: a "session" is the loaded engine, which the factory shares
between sessions, so connect and close cost nothing after the first load. Decoding and synthesis
run in threads, each with its own deadline: a stuck decoder fails one reply, never the loop.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import logging
import uuid
from collections import Counter, deque
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from typing import TypeVar

from by_your_command.agents.events import (
    AssistantAudio,
    AssistantText,
    AssistantTranscript,
    ProviderError,
    ProviderEvent,
    ResponseDone,
    ResponseStatus,
    ToolCall,
    UserTranscript,
)
from by_your_command.agents.provider import (
    ProviderClosed,
    ProviderFailure,
    SessionSetup,
    ToolResult,
    ToolSpec,
)
from by_your_command.agents.providers.event_stream import EventStream
from by_your_command.agents.providers.local.config import OfflineConfig
from by_your_command.agents.providers.local.engine import Engine, LocalEngine
from by_your_command.agents.providers.local.replies import (
    late_result,
    parse_tool_result,
    refusal,
    success,
)
from by_your_command.agents.providers.local.text import rejected
from by_your_command.agents.providers.session_guards import check_whole_samples, open_session
from by_your_command.agents.robot_tool import TOOL_NAME
from by_your_command.local_speech.recognizer import Recognition
from by_your_command.local_speech.replies import acknowledgement, answer
from by_your_command.local_speech.spoken import RecognitionKind
from by_your_command.local_speech.tool_phrases import PhraseLimits, select_phrases, tool_call

log = logging.getLogger(__name__)

SAMPLE_RATE = 16000  # what the recognizer's acoustic model expects; the runtime resamples to it
MAX_SESSION_S = 7 * 24 * 3600.0  # nothing to rotate: the engine is local
MAX_REPLY_S = 60.0  # synthesized audio beyond this is cut (reply texts are short and bounded)
_IDS_KEPT = 64  # interrupted replies and open tool calls remembered (bounded, whatever comes)
_MAX_JOBS = 16
T = TypeVar("T")


@dataclass
class OfflineStats:
    """What this session did, and everything it refused or cut (logged when it closes)."""

    voice_turns: int = 0
    text_turns: int = 0
    commands: int = 0
    answers: int = 0
    not_caught: int = 0
    not_caught_unsaid: int = 0  # the user already spoke again: no "I did not catch that" over them
    low_confidence: int = 0
    truncated_turns: int = 0
    dropped_audio_bytes: int = 0
    oversize_texts: int = 0
    decode_timeouts: int = 0
    speak_timeouts: int = 0
    speak_failures: int = 0
    interrupted: int = 0
    ignored_images: int = 0
    tool_calls: int = 0  # calls of the robot's own tools (robot_command calls are `commands`)
    unknown_tools: int = 0  # a phrase heard for a tool this session was not given (not caught)
    tool_progress: int = 0  # progress notes of long-running calls (nothing is said of them)
    tool_phrases_left_out: int = 0  # declared phrases the recognizer does not take (logged)
    calls_forgotten: int = 0  # open calls beyond the bound: their results are answered plainly


@dataclass(frozen=True)
class _Heard:
    pcm: bytes


@dataclass(frozen=True)
class _Typed:
    text: str


@dataclass(frozen=True)
class _Call:
    tool: str
    command: str  # robot_command's command ("" for the robot's other tools)


@dataclass(frozen=True)
class _Verdict:
    call: _Call | None  # the call it answers (None for a call id we never made, or forgot)
    output: str


_Job = _Heard | _Typed | _Verdict


class OfflineProvider:
    """One offline "session" (see agents/provider.py for the contract)."""

    name = "offline"
    input_sample_rate = SAMPLE_RATE
    max_session_s = MAX_SESSION_S

    def __init__(
        self,
        config: OfflineConfig | None = None,
        engine: Engine | None = None,
        now: Callable[[], datetime] = datetime.now,
    ) -> None:
        self.config = config or OfflineConfig()
        self.stats = OfflineStats()
        self._engine = engine or LocalEngine(self.config)
        self._now = now
        self._setup: SessionSetup | None = None
        self._closed = False
        self._audio = bytearray()
        self._max_audio_bytes = int(self.config.max_turn_s * SAMPLE_RATE) * 2
        self._dropped = 0  # bytes of the current turn beyond the limit
        # The runtime sends one turn at a time; the bound only stops a caller that does not.
        self._jobs: asyncio.Queue[_Job] = asyncio.Queue(_MAX_JOBS)
        self._events = EventStream(self.config.event_queue_size)
        self._worker: asyncio.Task[None] | None = None
        self._cancelled: deque[str] = deque(maxlen=_IDS_KEPT)
        self._speaking = ""  # the response whose audio is being emitted
        self._tag = uuid.uuid4().hex[:8]  # ids stay unique across sessions
        self._serial = itertools.count(1)
        self._replies = self.config.replies()
        self._calls: dict[str, _Call] = {}  # call id -> what it asked for, until its result is back

    # ---- session ----------------------------------------------------------------------------
    async def connect(self, setup: SessionSetup) -> None:
        if self._setup is not None or self._closed:
            raise ProviderClosed("a provider is one session: build a new one to reconnect")
        try:
            await asyncio.to_thread(self._engine.load)  # once per factory; later sessions return at once
        except (ImportError, OSError, ValueError, RuntimeError) as error:
            # No network to wait for: a missing model or a broken vocabulary will not fix itself.
            message = " ".join(f"the offline speech engine cannot start: {error}".split())
            raise ProviderFailure(ProviderError("offline_engine_unavailable", message, fatal=True)) from None
        if self._closed:
            raise ProviderClosed("closed while the engine loaded")
        try:  # a new set of tool phrases rebuilds the recognizer's search, off the loop
            left_out = await asyncio.to_thread(self._hear_tools, setup.tools)
            self.stats.tool_phrases_left_out = sum(left_out.values())
        except (ValueError, RuntimeError, OSError) as error:
            # Commands, questions and the tools typed or heard before still work: not fatal.
            log.exception("offline provider: the tools' phrases could not be added")
            await self._emit(
                ProviderError("offline_tools_unheard", f"the tools' phrases are not heard: {error}")
            )
        if self._closed:
            raise ProviderClosed("closed while the tools' phrases were added")
        self._setup = setup
        self._worker = asyncio.ensure_future(self._work())

    def _hear_tools(self, tools: Sequence[ToolSpec]) -> Counter[str]:
        """Blocking (a catalog may declare thousands of phrases): the engine hears the tools'
        phrases, selected and bounded; returns every phrase left out, by reason."""
        limits = PhraseLimits(self.config.max_tool_phrases, self.config.max_tool_phrase_words)
        declared = [(tool.name, said, arguments) for tool in tools for said, arguments in tool.spoken]
        selection = select_phrases(declared, limits)
        return selection.cut + self._engine.use_tools(selection.phrases)

    async def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._worker is not None:
            self._worker.cancel()
            await asyncio.gather(self._worker, return_exceptions=True)
        self._events.end()
        log.info("offline session closed: %s", self.stats)

    def _live(self) -> SessionSetup:
        return open_session(self._closed, self._setup, "the offline session")

    # ---- input ------------------------------------------------------------------------------
    async def send_audio(self, pcm: bytes) -> None:
        check_whole_samples(pcm)
        self._live()
        room = self._max_audio_bytes - len(self._audio)
        self._audio += pcm[: max(room, 0)]
        self._dropped += max(len(pcm) - max(room, 0), 0)

    async def end_of_turn(self) -> None:
        self._live()
        pcm, self._audio = bytes(self._audio), bytearray()
        if self._dropped:
            self.stats.truncated_turns += 1
            self.stats.dropped_audio_bytes += self._dropped
            seconds = self._dropped / (2 * SAMPLE_RATE)
            self._dropped = 0
            await self._emit(
                ProviderError(
                    "audio_truncated",
                    f"a turn longer than {self.config.max_turn_s:g} s: its last {seconds:.1f} s not decoded",
                )
            )
        self._jobs.put_nowait(_Heard(pcm))

    async def send_text(self, text: str) -> None:
        self._live()
        self._jobs.put_nowait(_Typed(text))

    async def add_context(self, text: str) -> None:
        self._live()  # no model keeps a history here: nothing to tell

    async def send_image(self, jpeg: bytes) -> None:
        self._live()
        self.stats.ignored_images += 1  # nothing here can look at it

    async def send_tool_results(self, results: Sequence[ToolResult]) -> None:
        self._live()
        for result in results:
            self._jobs.put_nowait(_Verdict(self._calls.pop(result.call_id, None), result.output))

    async def send_tool_progress(self, call_id: str, text: str) -> None:
        self._live()
        self.stats.tool_progress += 1  # nothing is said: the result is, when the action ends

    async def interrupt(self, response_id: str, item_id: str, played_ms: int) -> None:
        self._live()
        cut = response_id or self._speaking
        if cut and cut not in self._cancelled:
            self._cancelled.append(cut)  # its audio still queued is dropped in events()
            self.stats.interrupted += 1

    # ---- output -----------------------------------------------------------------------------
    async def events(self) -> AsyncIterator[ProviderEvent]:
        async for event in self._events:
            if isinstance(event, AssistantAudio) and event.response_id in self._cancelled:
                continue  # a cut reply's audio still queued
            yield event

    async def _emit(self, event: ProviderEvent) -> None:
        await self._events.put(event)

    # ---- the worker: one job at a time, in the order the runtime sent them ---------------------
    async def _work(self) -> None:
        while True:
            job = await self._jobs.get()
            response_id = f"offline-{self._tag}-{next(self._serial)}"
            try:
                await self._run(job, response_id)
            except Exception as error:  # a bug must fail one reply, not leave the runtime waiting
                log.exception("offline provider: reply %s failed", response_id)
                await self._emit(ResponseDone(response_id, ResponseStatus.FAILED, reason=str(error)[:200]))

    async def _run(self, job: _Job, response_id: str) -> None:
        if isinstance(job, _Typed) and (output := late_result(job.text)) is not None:
            job = _Verdict(None, output)  # another session's action ended: its result is answered
        if isinstance(job, _Verdict):
            verdict = parse_tool_result(job.output)
            command = job.call.command if job.call is not None else ""
            if not verdict.accepted:
                text = refusal(self.config.refusal_text, verdict.reason)
            elif command:  # our own command, not the verdict's echo of it: that text came from outside
                text = acknowledgement(command, self._replies)
            else:
                text = success(verdict.message)
            await self._say(response_id, text)
            return
        if isinstance(job, _Typed):
            self.stats.text_turns += 1
            understood = self._understand_text(job.text)
        else:
            self.stats.voice_turns += 1
            decoded = await self._decode(job.pcm, response_id)
            if decoded is None:
                return
            understood = self._confident(decoded)
            if understood.kind is RecognitionKind.REJECTED and self._audio:
                # The user already speaks again: a late "I did not catch that" would talk over
                # them and, half duplex, cut their next command short. Nothing is said.
                self.stats.not_caught += 1
                self.stats.not_caught_unsaid += 1
                await self._emit(UserTranscript("", f"{response_id}-user"))
                await self._emit(ResponseDone(response_id, ResponseStatus.COMPLETED))
                return
            heard = understood.text.strip()
            if understood.kind is RecognitionKind.REJECTED:
                # The decoder's guess at chat is filler words: kept out of the transcript, which
                # other agents read (a cloud command agent could make a command of it).
                log.debug("offline: not caught (%s): %r", understood.reason, heard)
                heard = ""
            await self._emit(UserTranscript(heard, f"{response_id}-user"))
        await self._answer(understood, response_id)

    def _understand_text(self, text: str) -> Recognition:
        if len(text) > self.config.max_text_chars:
            self.stats.oversize_texts += 1
            return rejected(text, f"longer than {self.config.max_text_chars} characters")
        return self._engine.understand(text)

    async def _decode(self, pcm: bytes, response_id: str) -> Recognition | None:
        if not pcm:
            return rejected("", "no audio")
        try:
            return await self._offload(self.config.decode_timeout_s, self._engine.recognize, pcm, SAMPLE_RATE)
        except asyncio.TimeoutError:  # not the builtin before 3.11
            self.stats.decode_timeouts += 1
            reason = f"decoding took longer than {self.config.decode_timeout_s:g} s"
            await self._emit(ResponseDone(response_id, ResponseStatus.FAILED, reason=reason))
            return None

    def _confident(self, understood: Recognition) -> Recognition:
        if understood.kind is RecognitionKind.REJECTED or understood.confidence >= self.config.min_confidence:
            return understood
        self.stats.low_confidence += 1
        return rejected(understood.text, f"confidence {understood.confidence:.2f} below the threshold")

    async def _answer(self, understood: Recognition, response_id: str) -> None:
        setup = self._live()
        kind = understood.kind
        if kind is RecognitionKind.TOOL:
            name, arguments = tool_call(understood.canonical)
            if any(tool.name == name for tool in setup.tools):
                self.stats.tool_calls += 1
                await self._call(response_id, _Call(name, ""), arguments)
                return
            self.stats.unknown_tools += 1  # heard for another session's tools: not this one's to call
            kind = RecognitionKind.REJECTED
        if kind in (RecognitionKind.COMMAND, RecognitionKind.PHRASE):
            self.stats.commands += 1
            command = understood.canonical
            if any(tool.name == TOOL_NAME for tool in setup.tools):
                await self._call(response_id, _Call(TOOL_NAME, command), json.dumps({"command": command}))
            elif not setup.audio_out:  # a command agent: its text replies are published as commands
                await self._emit(AssistantText(response_id, f"{response_id}-item", command, final=True))
                await self._emit(ResponseDone(response_id, ResponseStatus.COMPLETED))
            else:  # a conversation agent without the tool: in dual mode the command agent acts
                await self._say(response_id, acknowledgement(command, self._replies))
            return
        if kind is RecognitionKind.QUESTION:
            self.stats.answers += 1
            await self._say(response_id, answer(understood.canonical, self._now(), self._replies))
            return
        self.stats.not_caught += 1
        await self._say(response_id, self.config.not_heard_text)

    async def _call(self, response_id: str, call: _Call, arguments: str) -> None:
        """The reply that calls a tool: the call, done. Its result is answered when it comes."""
        call_id = f"{response_id}-call"
        if len(self._calls) >= _IDS_KEPT:  # the runtime answers every call; bounded anyway
            self._calls.pop(next(iter(self._calls)))  # the oldest: its result is answered plainly
            self.stats.calls_forgotten += 1
        self._calls[call_id] = call
        await self._emit(ToolCall(response_id, call_id, call.tool, arguments))
        await self._emit(ResponseDone(response_id, ResponseStatus.COMPLETED))

    async def _say(self, response_id: str, text: str) -> None:
        """Speak `text` as one reply: audio chunks, the transcript, done (or done only when the
        agent does not speak, or there is nothing to say)."""
        setup = self._live()
        text = text.strip()
        if not text or not setup.audio_out:
            await self._emit(ResponseDone(response_id, ResponseStatus.COMPLETED))
            return
        try:
            pcm, rate = await self._offload(self.config.speak_timeout_s, self._engine.say, text)
        except asyncio.TimeoutError:  # not the builtin before 3.11
            self.stats.speak_timeouts += 1
            reason = f"speaking took longer than {self.config.speak_timeout_s:g} s"
            await self._emit(ResponseDone(response_id, ResponseStatus.FAILED, reason=reason))
            return
        except (ValueError, RuntimeError) as error:  # espeak-ng failed, or the text cannot be said
            self.stats.speak_failures += 1
            await self._emit(ResponseDone(response_id, ResponseStatus.FAILED, reason=str(error)[:200]))
            return
        item_id = f"{response_id}-item"
        pcm = pcm[: min(len(pcm) // 2, int(MAX_REPLY_S * rate)) * 2]  # whole samples, bounded
        step = max(2, rate * self.config.audio_chunk_ms // 1000 * 2)
        self._speaking = response_id
        try:
            for start in range(0, len(pcm), step):
                if response_id in self._cancelled:
                    break
                await self._emit(AssistantAudio(response_id, item_id, pcm[start : start + step], rate))
        finally:
            self._speaking = ""
        await self._emit(AssistantTranscript(response_id, item_id, text, final=True))
        status = ResponseStatus.CANCELLED if response_id in self._cancelled else ResponseStatus.COMPLETED
        await self._emit(ResponseDone(response_id, status))

    @staticmethod
    async def _offload(timeout_s: float, function: Callable[..., T], *args: object) -> T:
        """`function` in a thread, waited for at most `timeout_s` (the thread itself cannot be
        stopped: the engine's inputs are bounded so it ends, and its lock keeps calls in order)."""
        return await asyncio.wait_for(asyncio.to_thread(function, *args), timeout_s)
