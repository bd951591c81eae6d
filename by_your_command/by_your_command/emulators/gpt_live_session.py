"""One GPT-Live session of the emulator: the rules the real server enforces, replies from the script.
The server module owns the socket; this class sees parsed client events and answers with the SDK's
own server event models (openai.types.live).

Faithful (SDK types and docstrings, the Live guides): `session.start` first and `session.started`
with the resolved session (voice `marin`, PCM16 24 kHz unless set); the model, not the client,
decides when to speak and when to yield (there is no response.create / cancel / truncate for
client delegation: `response.*` is refused with the real server's "requires Responses delegation");
input and output audio in the session's format, output as `session.output_audio.delta` without
timestamps on the primary WebSocket, transcripts as `session.input_transcript.delta` /
`session.output_transcript.delta` with session-timeline `start_ms` / `end_ms` and no done event;
a client delegation is `session.delegation.created` (id, target client, offset_ms; no task text:
the client reads the task from the transcript) answered by `session.commentary.append` (spoken),
`session.thinking.append` (silent) or `session.instructions.append` with its `delegation_id`, each
acknowledged by its `*.appended` event; commentary or thinking cancels acknowledgements still
waiting for `acknowledgement_delay_ms`; mute / unmute acknowledged, muted input heard as silence;
`session.usage.updated` with cumulative seconds of open session (silence and muted time count);
`session.close` answered by `session.closed` (reason close_requested, final session, usage).
There is no interruption event in the SDK: a reply the user talks over just stops (its audio and
output transcript end where it was cut).

Invented: timing (100 ms audio deltas, as one published trace shows; transcripts sent at the end
of the user's speech, word by word), ids, the energy-based speech detector and its thresholds,
usage in whole seconds (floor; the one published trace shows an integer) every `usage_interval_ms`,
error codes and wording outside the SDK's examples (`session_not_started`,
`session_already_started`, `unsupported_delegation`, `not_emulated`, unknown `delegation_id`),
closing the connection after a refused `session.start`, the session expiry (3600 s), a commentary
without delegation being spoken as given, a reply queued behind a non-interruptible one.
Not emulated: Responses and Decisions delegation, decisions, audio fixtures, G.711 formats,
sideband and forks, context-window usage, compaction.
"""

from __future__ import annotations

import asyncio
import base64
import time
from collections import OrderedDict, deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from openai.types.live import (
    CommentaryAppendedEvent,
    DelegationCreatedEvent,
    InputAudioMutedEvent,
    InputAudioUnmutedEvent,
    InputTranscriptDeltaEvent,
    InstructionsAppendedEvent,
    OutputAudioDeltaEvent,
    OutputTranscriptDeltaEvent,
    SessionClosedEvent,
    SessionResource,
    SessionStartedEvent,
    SessionUpdatedEvent,
    SessionUsage,
    SessionUsageUpdatedEvent,
    ThinkingAppendedEvent,
)
from openai.types.live.delegation_created_event import Delegation
from pydantic import BaseModel, ValidationError

from by_your_command.emulators.gpt_live_script import Delegate, Say, Script, Turn
from by_your_command.emulators.gpt_live_wire import (
    ClientEventError,
    JsonObject,
    error_event,
    estimated_tokens,
    new_id,
    validate_client_event,
)
from by_your_command.emulators.openai_wire import decode_pcm
from by_your_command.emulators.synthetic_speech import speech_pcm

DEFAULT_RATE = 24_000
DEFAULT_VOICE = "marin"
CloseReason = Literal["close_requested", "expired", "content", "remote_hangup", "connection_lost"]


@dataclass(frozen=True)
class SessionLimits:
    max_append_bytes: int = 15 * 1024 * 1024  # one input_audio.append, decoded
    max_append_tokens: int = 500  # instructions / thinking / commentary content (documented)
    max_instructions_tokens: int = 16_384  # session.start instructions (documented)
    max_input_items: int = 128  # session.start input history (documented)
    max_delegations: int = 64  # remembered delegation ids; the oldest go first
    max_queued_replies: int = 16
    expires_after_s: int = 3600  # the session's expires_at (invented)


class ScriptCursor:
    """The script's turns, consumed one per user turn across every connection of one emulator."""

    def __init__(self, script: Script) -> None:
        self.script = script
        self._turns: deque[Turn] = deque(script.turns)

    def peek(self) -> Turn | None:
        return self._turns[0] if self._turns else None

    def next_turn(self) -> Turn:
        if self._turns:
            return self._turns.popleft()
        return Turn(self.script.default_reply, heard=self.script.default_heard)


@dataclass(frozen=True)
class SpeechChange:
    started: bool  # True: speech began at start_ms; False: it ended at end_ms
    start_ms: int
    end_ms: int = 0


class SpeechDetector:
    """Speech by energy, in 10 ms frames of PCM16: it starts once `min_speech_ms` of loud frames
    gathered (gaps shorter than `end_silence_ms` do not reset the count: syllables have gaps) and
    ends after `end_silence_ms` of quiet. Positions are milliseconds of audio fed."""

    def __init__(self, rate: int, threshold: float, min_speech_ms: int, end_silence_ms: int) -> None:
        self._frame_bytes = rate // 100 * 2
        self._threshold, self._min_speech_ms, self._end_silence_ms = threshold, min_speech_ms, end_silence_ms
        self._pending = bytearray()
        self.position_ms = 0
        self.speaking = False
        self._voiced_ms = self._quiet_ms = self._start_ms = 0

    def feed(self, pcm: bytes) -> list[SpeechChange]:
        self._pending += pcm
        whole = len(self._pending) // self._frame_bytes * self._frame_bytes
        frames = np.frombuffer(bytes(self._pending[:whole]), dtype="<i2").astype(np.float64)
        del self._pending[:whole]
        changes: list[SpeechChange] = []
        for frame in frames.reshape(-1, self._frame_bytes // 2):
            loud = float(np.sqrt(np.mean(frame * frame))) >= self._threshold
            self.position_ms += 10
            if loud:
                if self._voiced_ms == 0:
                    self._start_ms = self.position_ms - 10
                self._voiced_ms += 10
                self._quiet_ms = 0
            else:
                self._quiet_ms += 10
            if not self.speaking:
                if self._quiet_ms >= self._end_silence_ms:
                    self._voiced_ms = 0  # too little speech before a pause: a noise, not a turn
                elif self._voiced_ms >= self._min_speech_ms:
                    self.speaking = True
                    changes.append(SpeechChange(True, self._start_ms))
            elif self._quiet_ms >= self._end_silence_ms:
                self.speaking, self._voiced_ms = False, 0
                changes.append(SpeechChange(False, self._start_ms, self.position_ms - self._quiet_ms))
        return changes


class _Ended(Exception):
    """The session ended from inside a reply (a scripted fault): nothing more to say."""


@dataclass(frozen=True)
class _Job:
    turn: Turn  # interruptible, faults
    text: str | None = None  # words to say instead of the turn's reply (a commentary's answer)


class GptLiveSession:
    def __init__(
        self,
        send: Callable[[BaseModel], Awaitable[None]],
        close: Callable[[], Awaitable[None]],
        abort: Callable[[], None],
        cursor: ScriptCursor,
        limits: SessionLimits = SessionLimits(),
        on_interrupted: Callable[[str], None] | None = None,
    ) -> None:
        self._send, self._close, self._abort = send, close, abort
        self._cursor, self._script, self._limits = cursor, cursor.script, limits
        self._on_interrupted = on_interrupted
        self.started = self.closed = False
        self.resource: SessionResource | None = None
        self._rate = DEFAULT_RATE
        self._muted = False
        self._detector: SpeechDetector | None = None
        self._input_origin_ms: int | None = None  # session time of the first input audio
        self._t0 = 0.0
        self._reply: asyncio.Task[None] | None = None
        self._reply_turn: Turn | None = None
        self._spoken = ""  # what the running reply said so far
        self._queue: deque[_Job] = deque(maxlen=limits.max_queued_replies)
        self._delegations: OrderedDict[str, Say | None] = OrderedDict()  # id -> scripted answer, once
        self._ack_delay_ms = 0
        self._ack_epoch = 0  # commentary or thinking moves it: waiting acknowledgements are dropped
        self._idle: asyncio.Task[None] | None = None
        self._background: list[asyncio.Task[None]] = []

    # ---- plumbing ---------------------------------------------------------------------------
    def now_ms(self) -> int:
        """Milliseconds since session.started: the session timeline of every *_ms field."""
        return int((time.monotonic() - self._t0) * 1000)

    def usage_seconds(self) -> float:
        return float(int(time.monotonic() - self._t0)) if self.started else 0.0

    async def refuse(self, error: ClientEventError, client_event_id: str | None) -> None:
        """Answer a refused event; before the session started that also ends the connection."""
        await self._send(error_event(error.code, error.message, error.param, client_event_id))
        if not self.started and not self.closed:
            self.closed = True
            await self._close()

    async def stop(self) -> None:
        """The connection is gone: stop every task."""
        self.closed = True
        tasks = [task for task in (self._reply, self._idle, *self._background) if task is not None]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    async def end(self, reason: CloseReason, client_event_id: str | None = None) -> None:
        """session.closed with the final session and usage, then a normal close."""
        if self.closed or self.resource is None:
            return
        self.closed = True
        current = asyncio.current_task()
        for task in (self._reply, self._idle, *self._background):
            if task is not None and task is not current:
                task.cancel()
        event = SessionClosedEvent(
            type="session.closed",
            event_id=new_id("event"),
            reason=reason,
            session=self.resource,
            usage=SessionUsage(seconds=self.usage_seconds()),
        )
        if client_event_id is not None:
            event.client_event_id = client_event_id
        await self._send(event)
        await self._close()

    # ---- dispatch ---------------------------------------------------------------------------
    async def handle(self, event: JsonObject) -> None:
        """Apply one parsed client event; a refusal becomes an `error` event."""
        client_event_id = event.get("event_id") if isinstance(event.get("event_id"), str) else None
        if self.closed:
            return
        try:
            validate_client_event(event)
            kind = event["type"]
            if not self.started:
                if kind != "session.start":
                    raise ClientEventError(
                        "session_not_started",
                        "Send session.start first and wait for session.started.",
                        "type",
                    )
                await self._start(event, client_event_id)
                return
            handlers: dict[str, Callable[[JsonObject, str | None], Awaitable[None]]] = {
                "session.start": self._start_again,
                "session.update": self._update,
                "session.input_audio.append": self._append,
                "session.input_audio.mute": self._mute,
                "session.input_audio.unmute": self._mute,
                "session.instructions.append": self._context,
                "session.thinking.append": self._context,
                "session.commentary.append": self._context,
                "session.close": self._close_requested,
            }
            handler = handlers.get(kind)
            if handler is None:
                await self._not_handled(kind)
            else:
                await handler(event, client_event_id)
        except ClientEventError as error:
            await self.refuse(error, client_event_id)

    async def _not_handled(self, kind: str) -> None:
        if kind.startswith("response."):
            raise ClientEventError("unsupported_delegation", f"{kind} requires Responses delegation.")
        raise ClientEventError("not_emulated", f"{kind} is not emulated.", "type")

    # ---- session ----------------------------------------------------------------------------
    async def _start(self, event: JsonObject, client_event_id: str | None) -> None:
        config: JsonObject = event["session"]
        model = config["model"]
        known = self._script.known_models
        if known and model not in known:
            raise ClientEventError(
                "model_not_found",
                f"The model `{model}` does not exist or you do not have access to it.",
                "session.model",
            )
        delegation = config.get("delegation") or {"type": "client"}
        if delegation["type"] != "client":
            raise ClientEventError(
                "invalid_value",
                "This emulator serves client delegation only (omit session.delegation or use type client).",
                "session.delegation.type",
            )
        audio = config.get("audio") or {}
        audio_format = audio.get("format") or {"type": "audio/pcm", "rate": DEFAULT_RATE}
        if audio_format["type"] != "audio/pcm":
            raise ClientEventError(
                "invalid_value", "This emulator serves audio/pcm only.", "session.audio.format.type"
            )
        if estimated_tokens(config.get("instructions") or "") > self._limits.max_instructions_tokens:
            raise ClientEventError(
                "string_above_max_length",
                f"Instructions are limited to {self._limits.max_instructions_tokens} tokens.",
                "session.instructions",
            )
        if len(config.get("input") or []) > self._limits.max_input_items:
            raise ClientEventError(
                "array_above_max_length",
                f"At most {self._limits.max_input_items} input messages.",
                "session.input",
            )
        self._ack_delay_ms = int(delegation.get("acknowledgement_delay_ms") or 0)
        resolved: JsonObject = {
            "id": new_id("sess"),
            "expires_at": int(time.time()) + self._limits.expires_after_s,
            "model": model,
            "status": "active",
            "audio": {
                "format": audio_format,
                "output": {"voice": (audio.get("output") or {}).get("voice") or DEFAULT_VOICE},
            },
            "delegation": {"type": "client", "acknowledgement_delay_ms": self._ack_delay_ms},
            "store": bool(config.get("store", False)),
        }
        for key in ("instructions", "input", "safety_identifier", "triggers", "client"):
            if config.get(key) is not None:
                resolved[key] = config[key]
        try:
            self.resource = SessionResource.model_validate(resolved)
        except ValidationError as error:
            raise ClientEventError(
                "invalid_value", f"Invalid session: {error.errors()[0]['msg']}.", "session"
            ) from None
        self._rate = int(audio_format["rate"])
        script = self._script
        self._detector = SpeechDetector(
            self._rate, script.speech_rms, script.min_speech_ms, script.end_silence_ms
        )
        self._t0 = time.monotonic()
        self.started = True
        started = SessionStartedEvent(type="session.started", event_id=new_id("event"), session=self.resource)
        if client_event_id is not None:
            started.client_event_id = client_event_id
        await self._send(started)
        self._background.append(asyncio.create_task(self._report_usage()))
        if script.session_expiry_s is not None:
            self._background.append(asyncio.create_task(self._expire(script.session_expiry_s)))
        self._serve_queue()

    async def _start_again(self, _: JsonObject, __: str | None) -> None:
        raise ClientEventError("session_already_started", "The session has already started.", "type")

    async def _update(self, event: JsonObject, client_event_id: str | None) -> None:
        assert self.resource is not None
        update: JsonObject = event["session"]
        delegation = update.get("delegation")
        if delegation is not None:
            if delegation["type"] != "client":
                raise ClientEventError(
                    "invalid_value", "The delegation type cannot change.", "session.delegation.type"
                )
            if delegation.get("acknowledgement_delay_ms") is not None:
                self._ack_delay_ms = int(delegation["acknowledgement_delay_ms"])
        changes: JsonObject = {
            "delegation": {"type": "client", "acknowledgement_delay_ms": self._ack_delay_ms}
        }
        if update.get("triggers") is not None:
            changes["triggers"] = update["triggers"]
        self.resource = SessionResource.model_validate({**self.resource.to_dict(), **changes})
        updated = SessionUpdatedEvent(type="session.updated", event_id=new_id("event"), session=self.resource)
        if client_event_id is not None:
            updated.client_event_id = client_event_id
        await self._send(updated)

    async def _close_requested(self, _: JsonObject, client_event_id: str | None) -> None:
        await self.end("close_requested", client_event_id)

    async def _report_usage(self) -> None:
        while True:
            await asyncio.sleep(self._script.usage_interval_ms / 1000)
            usage = SessionUsage(seconds=self.usage_seconds())
            await self._send(
                SessionUsageUpdatedEvent(type="session.usage.updated", event_id=new_id("event"), usage=usage)
            )

    async def _expire(self, after_s: float) -> None:
        await asyncio.sleep(after_s)
        await self.end("expired")

    # ---- input audio ------------------------------------------------------------------------
    async def _append(self, event: JsonObject, _: str | None) -> None:
        assert self._detector is not None
        pcm = decode_pcm(event["audio"], "audio")
        if len(pcm) > self._limits.max_append_bytes:
            raise ClientEventError(
                "audio_too_large",
                f"One append carries at most {self._limits.max_append_bytes} bytes.",
                "audio",
            )
        if self._input_origin_ms is None:
            self._input_origin_ms = self.now_ms()
        if self._muted:
            pcm = bytes(len(pcm))  # a muted input reaches the model as silence
        for change in self._detector.feed(pcm):
            if change.started:
                await self._speech_started()
            else:
                await self._speech_ended(change.start_ms, change.end_ms)

    async def _mute(self, event: JsonObject, client_event_id: str | None) -> None:
        self._muted = event["type"] == "session.input_audio.mute"
        ack: InputAudioMutedEvent | InputAudioUnmutedEvent
        if self._muted:
            ack = InputAudioMutedEvent(type="session.input_audio.muted", event_id=new_id("event"))
        else:
            ack = InputAudioUnmutedEvent(type="session.input_audio.unmuted", event_id=new_id("event"))
        if client_event_id is not None:
            ack.client_event_id = client_event_id
        await self._send(ack)

    async def _speech_started(self) -> None:
        self._cancel_idle()
        reply, turn = self._reply, self._reply_turn
        if reply is None or turn is None or not turn.interruptible:
            return
        reply.cancel()  # the model yields: its audio and transcript stop where they were
        await asyncio.gather(reply, return_exceptions=True)
        if self._on_interrupted is not None:
            self._on_interrupted(self._spoken)

    async def _speech_ended(self, start_ms: int, end_ms: int) -> None:
        turn = self._cursor.next_turn()
        origin = self._input_origin_ms or 0
        await self._transcribe_input(turn.heard, origin + start_ms, origin + end_ms)
        self._queue.append(_Job(turn))
        self._serve_queue()

    async def _transcribe_input(self, heard: str, start_ms: int, end_ms: int) -> None:
        words = heard.split(" ")
        step = max(0, end_ms - start_ms) / max(1, len(words))
        for index, word in enumerate(words):
            await self._send(
                InputTranscriptDeltaEvent(
                    type="session.input_transcript.delta",
                    event_id=new_id("event"),
                    delta=word if index == 0 else " " + word,
                    start_ms=int(start_ms + index * step),
                    end_ms=int(start_ms + (index + 1) * step),
                )
            )

    # ---- context: instructions, thinking, commentary ------------------------------------------
    async def _context(self, event: JsonObject, client_event_id: str | None) -> None:
        kind: str = event["type"]
        content: str = event["content"]
        delegation_id: str | None = event["delegation_id"]
        if estimated_tokens(content) > self._limits.max_append_tokens:
            raise ClientEventError(
                "string_above_max_length",
                f"'content' is limited to {self._limits.max_append_tokens} tokens.",
                "content",
            )
        if delegation_id is not None and delegation_id not in self._delegations:
            raise ClientEventError(
                "invalid_value", f"No client delegation with id '{delegation_id[:64]}'.", "delegation_id"
            )
        now = self.now_ms()
        ack: InstructionsAppendedEvent | ThinkingAppendedEvent | CommentaryAppendedEvent
        fields: dict[str, Any] = {"event_id": new_id("event"), "start_ms": now, "end_ms": now}
        if kind == "session.instructions.append":
            ack = InstructionsAppendedEvent(type="session.instructions.appended", **fields)
        elif kind == "session.thinking.append":
            ack = ThinkingAppendedEvent(type="session.thinking.appended", **fields)
        else:
            ack = CommentaryAppendedEvent(type="session.commentary.appended", **fields)
        if client_event_id is not None:
            ack.client_event_id = client_event_id
        if kind != "session.instructions.append":
            self._ack_epoch += 1
        await self._send(ack)
        if kind != "session.commentary.append":
            return
        scripted = self._delegations.get(delegation_id) if delegation_id is not None else None
        if delegation_id is not None:
            self._delegations[delegation_id] = None  # the scripted answer is for the first result only
        text = scripted.text if scripted is not None else content
        self._queue.append(_Job(Turn(Say(text)), text))
        self._serve_queue()

    # ---- replies ----------------------------------------------------------------------------
    def _serve_queue(self) -> None:
        """Start the next reply if the model is free and the user is not speaking."""
        if self.closed or self._reply is not None:
            return
        if self._detector is not None and self._detector.speaking:
            return
        if not self._queue:
            self._schedule_idle()
            return
        self._cancel_idle()
        job = self._queue.popleft()
        self._reply_turn = job.turn
        self._reply = asyncio.create_task(self._run(job))

    async def _run(self, job: _Job) -> None:
        self._spoken = ""
        try:
            if job.text is not None:
                await self._speak(job.text, job.turn)
            elif isinstance(job.turn.reply, Say):
                await self._speak(job.turn.reply.text, job.turn)
            elif isinstance(job.turn.reply, Delegate):
                await self._delegate(job.turn.reply, job.turn)
        except (_Ended, ConnectionResetError):
            return
        finally:
            if self._reply is asyncio.current_task():
                self._reply, self._reply_turn = None, None
        self._serve_queue()

    async def _speak(self, text: str, turn: Turn) -> None:
        script = self._script
        bytes_per_ms = self._rate * 2 // 1000
        pcm = speech_pcm(text, script.ms_per_char, self._rate)
        step = script.delta_ms * bytes_per_ms
        origin, sent_ms, said = self.now_ms(), 0, 0
        for offset in range(0, len(pcm), step):
            await self._fault(turn, sent_ms)
            chunk = pcm[offset : offset + step]
            await self._send(
                OutputAudioDeltaEvent(
                    type="session.output_audio.delta", delta=base64.b64encode(chunk).decode()
                )
            )
            sent_ms += len(chunk) // bytes_per_ms
            spoken = min(len(text), sent_ms // script.ms_per_char)
            if spoken > said:
                self._spoken = text[:spoken]  # before the send: a cut there still finds it said
                await self._say_transcript(text, said, spoken, origin)
                said = spoken
            await asyncio.sleep(len(chunk) / bytes_per_ms / 1000 * script.pace)
        if said < len(text):
            await self._say_transcript(text, said, len(text), origin)
        self._spoken = text

    async def _say_transcript(self, text: str, start: int, end: int, origin_ms: int) -> None:
        ms_per_char = self._script.ms_per_char
        await self._send(
            OutputTranscriptDeltaEvent(
                type="session.output_transcript.delta",
                event_id=new_id("event"),
                delta=text[start:end],
                start_ms=origin_ms + start * ms_per_char,
                end_ms=origin_ms + end * ms_per_char,
            )
        )

    async def _fault(self, turn: Turn, sent_ms: int) -> None:
        if turn.drop_after_ms is not None and sent_ms >= turn.drop_after_ms:
            self._abort()
            raise ConnectionResetError("fault injection: connection dropped mid-reply")
        if turn.close_after_ms is not None and sent_ms >= turn.close_after_ms:
            await self.end("content")
            raise _Ended

    async def _delegate(self, delegate: Delegate, turn: Turn) -> None:
        delegation_id = new_id("dlg")
        self._delegations[delegation_id] = delegate.then
        while len(self._delegations) > self._limits.max_delegations:
            self._delegations.popitem(last=False)
        await self._send(
            DelegationCreatedEvent(
                type="session.delegation.created",
                event_id=new_id("event"),
                offset_ms=self.now_ms(),
                delegation=Delegation(id=delegation_id, target="client", type="delegation"),
            )
        )
        if delegate.acknowledge is None:
            return
        acknowledgement = _Job(turn, delegate.acknowledge.text)
        if self._ack_delay_ms == 0:
            self._queue.appendleft(acknowledgement)  # said as soon as this job ends
            return
        self._background = [task for task in self._background if not task.done()]
        self._background.append(asyncio.create_task(self._acknowledge_later(acknowledgement)))

    async def _acknowledge_later(self, acknowledgement: _Job) -> None:
        epoch = self._ack_epoch
        await asyncio.sleep(self._ack_delay_ms / 1000)
        if epoch == self._ack_epoch:  # no commentary or thinking came first
            self._queue.append(acknowledgement)
            self._serve_queue()

    # ---- the model speaking first -------------------------------------------------------------
    def _schedule_idle(self) -> None:
        self._cancel_idle()
        head = self._cursor.peek()
        if head is not None and head.after_ms is not None and not self.closed:
            self._idle = asyncio.create_task(self._speak_first(head, head.after_ms))

    def _cancel_idle(self) -> None:
        if self._idle is not None and self._idle is not asyncio.current_task():
            self._idle.cancel()
        self._idle = None

    async def _speak_first(self, head: Turn, after_ms: int) -> None:
        await asyncio.sleep(after_ms / 1000)
        if self._cursor.peek() is head:
            self._idle = None
            self._queue.append(_Job(self._cursor.next_turn()))
            self._serve_queue()
