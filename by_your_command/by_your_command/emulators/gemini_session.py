"""One Gemini Live connection of the emulator, after `setupComplete`: the rules the real server
enforces, replies from the script. The server module owns the socket; this class sees parsed
messages and answers through callbacks.

Faithful (protocols.md B, C.4): message and field names, one modality per session, activityStart /
activityEnd only with automatic activity detection disabled, `interrupted` then `turnComplete`
(no generationComplete) for a cut reply, clientContent turnComplete interrupting a reply, toolCall
ids answered by toolResponse, toolCallCancellation of calls still waiting when the user interrupts,
handles honoured on resumption. Invented: timing, transcripts, token counts, usageMetadata riding on
the turnComplete message, the goAway schedule, a turnComplete after a cancellation, scripted
cancellations (`cancel_after_ms`), a toolResponse for a cancelled call being ignored (counted).
Not emulated: automatic activity detection (audio is only answered after audioStreamEnd), thinking,
grounding, context window compression. NON_BLOCKING functions (3.8-live): the toolCall ends the
model turn (turnComplete) and the conversation goes on; a user turn does not cancel them; a
functionResponse with willContinue keeps the call open (progress, no reply); the final one is
answered per its scheduling (SILENT: never, WHEN_IDLE (also when absent, invented): once no reply
runs, INTERRUPT: at once). willContinue or scheduling for a BLOCKING function is refused.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import math
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from by_your_command.emulators.gemini_script import CallTool, Say, Script, Silence, Turn
from by_your_command.emulators.gemini_wire import (
    CLOSE_INTERNAL,
    DEADLINE_EXPIRED,
    INVALID_ARGUMENT,
    JsonObject,
    WireError,
    bool_field,
    decode_blob,
    duration_text,
    field_value,
    list_field,
    obj_field,
    pcm_rate,
    str_field,
)
from by_your_command.emulators.synthetic_speech import speech_pcm

OUTPUT_RATE = 24_000  # Gemini Live always answers 24 kHz mono s16le
OUTPUT_MIME = f"audio/pcm;rate={OUTPUT_RATE}"
AUDIO_TOKENS_PER_S = 25  # invented (real models count about 25-32 tokens per second of audio)
IMAGE_MIME_TYPES = ("image/jpeg", "image/png", "image/webp")
NO_SPEECH = "NEED_MORE_INPUT"  # the turnCompleteReason of an activity without speech (invented)
SETUP_KEYS = {
    "model",
    "generationConfig",
    "systemInstruction",
    "tools",
    "realtimeInputConfig",
    "sessionResumption",
    "contextWindowCompression",
    "inputAudioTranscription",
    "outputAudioTranscription",
    "proactivity",
    "historyConfig",
    "explicitVadSignal",
}


@dataclass(frozen=True)
class SessionLimits:
    max_turn_audio_ms: int = 15 * 60 * 1000  # one user activity (bounded memory and tokens)
    max_frame_bytes: int = 7 * 1024 * 1024  # one camera frame


@dataclass(frozen=True)
class SessionConfig:
    """What a `setup` message asked for (validated)."""

    model: str
    audio_out: bool
    voice: str
    instructions: str
    input_transcription: bool
    output_transcription: bool
    manual_activity: bool  # automaticActivityDetection.disabled
    interrupts: bool  # activityHandling is not NO_INTERRUPTION
    resumption: bool
    resume_handle: str | None
    functions: tuple[str, ...]
    non_blocking: frozenset[str] = frozenset()  # functions declared with behavior NON_BLOCKING

    @staticmethod
    def from_setup(setup: JsonObject) -> SessionConfig:
        for key in setup:
            if key not in SETUP_KEYS and _camel(key) not in SETUP_KEYS:
                raise WireError(f"Invalid JSON payload received. Unknown name \"{key}\" at 'setup'.")
        model = str_field(setup, "model", "setup")
        if not model:
            raise WireError(f"{INVALID_ARGUMENT} 'setup.model' is required.")
        generation = obj_field(setup, "generationConfig", "setup") or {}
        modalities = [
            str(m).upper() for m in list_field(generation, "responseModalities", "setup.generationConfig")
        ]
        if len(modalities) > 1 or any(m not in ("AUDIO", "TEXT") for m in modalities):
            raise WireError(f"{INVALID_ARGUMENT} responseModalities takes one of AUDIO or TEXT.")
        speech = obj_field(generation, "speechConfig", "setup.generationConfig") or {}
        voice_config = obj_field(speech, "voiceConfig", "speechConfig") or {}
        prebuilt = obj_field(voice_config, "prebuiltVoiceConfig", "voiceConfig") or {}
        realtime = obj_field(setup, "realtimeInputConfig", "setup") or {}
        detection = obj_field(realtime, "automaticActivityDetection", "realtimeInputConfig") or {}
        resumption = obj_field(setup, "sessionResumption", "setup")
        return SessionConfig(
            model=model.removeprefix("models/"),
            audio_out=modalities != ["TEXT"],
            voice=str_field(prebuilt, "voiceName", "prebuiltVoiceConfig") or "Puck",
            instructions=_content_text(obj_field(setup, "systemInstruction", "setup") or {}),
            input_transcription=obj_field(setup, "inputAudioTranscription", "setup") is not None,
            output_transcription=obj_field(setup, "outputAudioTranscription", "setup") is not None,
            manual_activity=bool_field(detection, "disabled", "automaticActivityDetection"),
            interrupts=field_value(realtime, "activityHandling") != "NO_INTERRUPTION",
            resumption=resumption is not None,
            resume_handle=str_field(resumption, "handle", "sessionResumption") if resumption else None,
            functions=_function_names(setup),
            non_blocking=_non_blocking(setup),
        )


@dataclass
class Conversation:
    """What the model has in context: token counts by modality and a readable transcript."""

    text_tokens: int = 0
    audio_ms: int = 0
    frames: int = 0
    transcript: deque[tuple[str, str]] = field(default_factory=lambda: deque(maxlen=512))

    def copy(self) -> Conversation:
        return Conversation(
            self.text_tokens, self.audio_ms, self.frames, deque(self.transcript, self.transcript.maxlen)
        )

    def add_text(self, role: str, text: str) -> None:
        if text:
            self.text_tokens += _tokens(text)
            self.transcript.append((role, text))


@dataclass
class _UserInput:
    audio_ms: int = 0
    frames: int = 0
    sound: bool = False  # any non-zero sample: digital silence holds no speech


@dataclass
class _Reply:
    turn: Turn
    task: asyncio.Task[None] | None = None
    said: str = ""  # the part of the reply the client has been sent
    audio_ms: int = 0
    prompt: JsonObject = field(default_factory=dict)  # usage of the context when it began
    finishing: bool = False  # generation is complete: an interruption comes too late to cut it


class ScriptCursor:
    """The script's turns, consumed one per model turn across every connection of one emulator."""

    def __init__(self, script: Script) -> None:
        self.script = script
        self._turns: deque[Turn] = deque(script.turns)

    def next_turn(self) -> Turn:
        return (
            self._turns.popleft()
            if self._turns
            else Turn(self.script.default_reply, self.script.default_heard)
        )


Send = Callable[[JsonObject], Awaitable[None]]
Close = Callable[[int, str], Awaitable[None]]
IssueHandle = Callable[[Conversation], str]


class GeminiLiveSession:
    def __init__(
        self,
        config: SessionConfig,
        conversation: Conversation,
        cursor: ScriptCursor,
        send: Send,
        close: Close,
        abort: Callable[[], None],
        issue_handle: IssueHandle,
        limits: SessionLimits = SessionLimits(),
    ) -> None:
        self.config, self.conversation, self._cursor = config, conversation, cursor
        self._script = cursor.script
        self._send, self._close, self._abort, self._issue_handle = send, close, abort, issue_handle
        self._limits = limits
        self._activity: _UserInput | None = None  # an open activityStart … activityEnd
        self._pending = _UserInput()  # audio/frames not yet answered (outside an activity)
        self._reply: _Reply | None = None
        self._calls: dict[str, CallTool] = {}  # toolCall id → the call awaiting its toolResponse
        self._running: dict[str, CallTool] = {}  # NON_BLOCKING calls not finally answered yet
        self._when_idle: deque[Turn] = deque()  # replies to NON_BLOCKING results, after the current one
        self.progress_responses = 0  # willContinue functionResponses (progress of NON_BLOCKING calls)
        self._cancelled: deque[str] = deque(maxlen=256)  # ids withdrawn by toolCallCancellation
        self.cancelled_responses = 0  # toolResponses for cancelled calls (ignored)
        self._timers: list[asyncio.Task[None]] = []
        self.model_turns = 0
        self.audio_outside_activity_ms = 0  # audio a manual-activity client sent between activities

    # ---- plumbing ---------------------------------------------------------------------------
    async def start(self) -> None:
        if self._script.deadline_s is not None:
            self._timers.append(asyncio.ensure_future(self._expire(self._script.deadline_s)))

    async def stop(self) -> None:
        tasks = [*self._timers, *([self._reply.task] if self._reply and self._reply.task else [])]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    async def _expire(self, after_s: float) -> None:
        await asyncio.sleep(after_s)
        await self._close(CLOSE_INTERNAL, DEADLINE_EXPIRED)

    def _generating(self) -> bool:
        return self._reply is not None and self._reply.task is not None and not self._reply.task.done()

    # ---- dispatch ---------------------------------------------------------------------------
    async def handle(self, kind: str, body: JsonObject) -> None:
        if kind == "setup":
            raise WireError(f"{INVALID_ARGUMENT} setup may only be sent once, first.")
        if kind == "realtimeInput":
            await self._realtime_input(body)
        elif kind == "clientContent":
            await self._client_content(body)
        else:
            await self._tool_response(body)

    async def _realtime_input(self, body: JsonObject) -> None:
        where = "realtimeInput"
        if field_value(body, "activityStart") is not None:
            self._need_manual("activityStart")
            if self._activity is None:
                self._activity = _UserInput()
                if self.config.interrupts:
                    await self._interrupt()
        audio = obj_field(body, "audio", where)
        for blob in ([audio] if audio is not None else []) + list_field(body, "mediaChunks", where):
            if not isinstance(blob, dict):
                raise WireError(f"{INVALID_ARGUMENT} '{where}.mediaChunks' holds blobs.")
            mime = str_field(blob, "mimeType", where) or ""
            if mime.startswith("image/"):
                self._frame(blob, mime)
            else:
                self._audio(blob, mime)
        video = obj_field(body, "video", where)
        if video is not None:
            self._frame(video, str_field(video, "mimeType", where) or "")
        text = str_field(body, "text", where)
        if text:
            await self._user_turn(text)
        if field_value(body, "activityEnd") is not None:
            self._need_manual("activityEnd")
            if self._activity is not None:
                activity, self._activity = self._activity, None
                if activity.sound:
                    await self._user_turn(None, activity)
                else:
                    await self._no_speech()
        if bool_field(body, "audioStreamEnd", where) and not self.config.manual_activity:
            if self._pending.audio_ms:
                await self._user_turn(None)

    def _need_manual(self, name: str) -> None:
        if not self.config.manual_activity:
            raise WireError(
                f"{INVALID_ARGUMENT} {name} needs automaticActivityDetection.disabled in the setup."
            )

    def _audio(self, blob: JsonObject, mime: str) -> None:
        if not mime.startswith("audio/pcm"):
            raise WireError(f"{INVALID_ARGUMENT} Unsupported audio mimeType {mime[:40]!r}.")
        pcm = decode_blob(field_value(blob, "data"), "audio")
        if len(pcm) % 2:
            raise WireError(f"{INVALID_ARGUMENT} PCM16 audio needs whole samples.")
        ms = len(pcm) * 1000 // (2 * pcm_rate(mime))
        if self.config.manual_activity and self._activity is None:
            self.audio_outside_activity_ms += ms  # not part of any turn: the model never hears it
            return
        target = self._activity or self._pending
        if target.audio_ms + ms > self._limits.max_turn_audio_ms:
            raise WireError(
                f"{INVALID_ARGUMENT} A user turn holds at most {self._limits.max_turn_audio_ms} ms."
            )
        target.audio_ms += ms
        target.sound = target.sound or pcm.count(0) != len(pcm)

    def _frame(self, blob: JsonObject, mime: str) -> None:
        if mime not in IMAGE_MIME_TYPES:
            raise WireError(f"{INVALID_ARGUMENT} Unsupported image mimeType {mime[:40]!r}.")
        data = decode_blob(field_value(blob, "data"), "video")
        if not data or len(data) > self._limits.max_frame_bytes:
            raise WireError(f"{INVALID_ARGUMENT} An image holds 1 to {self._limits.max_frame_bytes} bytes.")
        (self._activity or self._pending).frames += 1

    async def _client_content(self, body: JsonObject) -> None:
        texts: list[str] = []
        for index, content in enumerate(list_field(body, "turns", "clientContent")):
            where = f"clientContent.turns[{index}]"
            if not isinstance(content, dict):
                raise WireError(f"{INVALID_ARGUMENT} '{where}' must be a Content object.")
            role = str_field(content, "role", where) or "user"
            if role not in ("user", "model"):
                raise WireError(f"{INVALID_ARGUMENT} '{where}.role' must be user or model.")
            text = _content_text(content)
            self.conversation.add_text(role, text)
            if role == "user":
                texts.append(text)
        if bool_field(body, "turnComplete", "clientContent"):
            await self._interrupt()  # 3.8: turnComplete always interrupts a reply in progress
            await self._user_turn(" ".join(texts) or None, recorded=True)

    async def _tool_response(self, body: JsonObject) -> None:
        answered: list[CallTool] = []
        for index, response in enumerate(list_field(body, "functionResponses", "toolResponse")):
            where = f"toolResponse.functionResponses[{index}]"
            if not isinstance(response, dict):
                raise WireError(f"{INVALID_ARGUMENT} '{where}' must be an object.")
            call_id = str_field(response, "id", where) or ""
            if call_id in self._running:
                await self._non_blocking_response(call_id, response, where)
                continue
            if field_value(response, "willContinue") is not None or field_value(response, "scheduling"):
                raise WireError(
                    f"{INVALID_ARGUMENT} '{where}': willContinue and scheduling need a NON_BLOCKING function."
                )
            call = self._calls.pop(call_id, None)
            if call is None and call_id in self._cancelled:
                self.cancelled_responses += 1  # too late: the call was withdrawn
                continue
            if call is None:
                raise WireError(f"{INVALID_ARGUMENT} '{where}.id' names no pending function call.")
            if str_field(response, "name", where) not in (None, call.name):
                raise WireError(f"{INVALID_ARGUMENT} '{where}.name' does not match the call.")
            result = obj_field(response, "response", where) or {}
            self.conversation.add_text("tool", json.dumps(result))
            answered.append(call)
        if answered and not self._calls:
            self._begin(Turn(answered[-1].then))

    async def _non_blocking_response(self, call_id: str, response: JsonObject, where: str) -> None:
        call = self._running[call_id]
        if str_field(response, "name", where) not in (None, call.name):
            raise WireError(f"{INVALID_ARGUMENT} '{where}.name' does not match the call.")
        scheduling = str_field(response, "scheduling", where) or "WHEN_IDLE"
        if scheduling not in ("SILENT", "WHEN_IDLE", "INTERRUPT", "SCHEDULING_UNSPECIFIED"):
            raise WireError(f"{INVALID_ARGUMENT} Invalid value at '{where}.scheduling'.")
        self.conversation.add_text("tool", json.dumps(obj_field(response, "response", where) or {}))
        if bool_field(response, "willContinue", where):
            self.progress_responses += 1
            return
        del self._running[call_id]
        if scheduling == "SILENT":
            return
        if scheduling == "INTERRUPT":
            await self._interrupt()
        if self._generating():
            self._when_idle.append(Turn(call.then))
        else:
            self._begin(Turn(call.then))

    # ---- replies ----------------------------------------------------------------------------
    async def _user_turn(
        self, text: str | None, activity: _UserInput | None = None, recorded: bool = False
    ) -> None:
        """Answer a user turn: an activity's audio, a text, and whatever frames came with it."""
        pending, self._pending = self._pending, _UserInput()
        audio_ms = pending.audio_ms + (activity.audio_ms if activity else 0)
        frames = pending.frames + (activity.frames if activity else 0)
        await self._interrupt()
        turn = self._cursor.next_turn()
        if audio_ms and self.config.input_transcription:
            words = turn.heard.split(" ")
            for index, word in enumerate(words):
                piece: JsonObject = {"text": word if index == 0 else " " + word}
                if index == len(words) - 1:
                    piece["finished"] = True
                await self._send({"serverContent": {"inputTranscription": piece}})
        self.conversation.add_text("user", turn.heard if audio_ms else "" if recorded else text or "")
        self.conversation.audio_ms += audio_ms
        self.conversation.frames += frames
        self._begin(turn)

    async def _no_speech(self) -> None:
        """An activity without speech (no audio, or digital silence): nothing to answer. The model
        turn is a bare turnComplete saying so; no script turn is consumed. Invented: the reason
        (a real server may send nothing at all)."""
        await self._send({"serverContent": {"turnComplete": True, "turnCompleteReason": NO_SPEECH}})

    def _begin(self, turn: Turn) -> None:
        reply = _Reply(turn, prompt=self._prompt_usage())
        self._reply = reply
        reply.task = asyncio.ensure_future(self._run(reply))

    async def _interrupt(self) -> None:
        """Stop the reply in progress: `interrupted`, then `turnComplete` (the server's own history
        keeps what was sent; there is no truncate in Gemini). Calls still waiting are cancelled."""
        if self._calls:
            await self._cancel_calls(list(self._calls))
        reply = self._reply
        if reply is None or reply.task is None or reply.task.done():
            return
        if reply.finishing:  # its turnComplete is on the way: let it go out, in order
            await asyncio.gather(reply.task, return_exceptions=True)
            return
        reply.task.cancel()
        await asyncio.gather(reply.task, return_exceptions=True)
        await self._send({"serverContent": {"interrupted": True}})
        await self._end_turn(reply)

    async def _run(self, reply: _Reply) -> None:
        content = reply.turn.reply
        try:
            if isinstance(content, Silence):
                await asyncio.Future()  # only an interruption ends it
            elif isinstance(content, CallTool):
                call_id = f"function-call-{id(reply):x}-{self.model_turns}"
                non_blocking = content.name in self.config.non_blocking
                (self._running if non_blocking else self._calls)[call_id] = content
                call = {"id": call_id, "name": content.name, "args": json.loads(content.arguments)}
                await self._send({"toolCall": {"functionCalls": [call]}})
                self.conversation.add_text("model", f"{content.name}({content.arguments})")
                if non_blocking:  # the model turn ends; the call runs on (its result comes later)
                    reply.finishing = True
                    await self._end_turn(reply)
                    self._next_when_idle()
                    return
                if reply.turn.cancel_after_ms is not None:
                    self._timers.append(
                        asyncio.ensure_future(self._cancel_later(call_id, reply.turn.cancel_after_ms))
                    )
                return  # BLOCKING: the model waits for the toolResponse; no turnComplete yet
            elif content.modality == "text" or not self.config.audio_out:
                await self._stream_text(reply, content)
            else:
                await self._stream_audio(reply, content)
        except ConnectionResetError:
            return  # a fault dropped the connection
        reply.finishing = True
        await self._send({"serverContent": {"generationComplete": True}})
        await self._end_turn(reply)
        self._next_when_idle()

    def _next_when_idle(self) -> None:
        """A NON_BLOCKING result's reply waited for this one to end (this task ends right after)."""
        if self._when_idle:
            self._begin(self._when_idle.popleft())

    async def _cancel_later(self, call_id: str, after_ms: int) -> None:
        await asyncio.sleep(after_ms / 1000)
        if call_id in self._calls:
            await self._cancel_calls([call_id])

    async def _cancel_calls(self, call_ids: list[str]) -> None:
        """toolCallCancellation for calls still waiting, then the turn that made them ends."""
        for call_id in call_ids:
            self._calls.pop(call_id, None)
            self._cancelled.append(call_id)
        await self._send({"toolCallCancellation": {"ids": call_ids}})
        reply = self._reply
        if reply is not None and not self._calls:
            await self._end_turn(reply)

    async def _stream_text(self, reply: _Reply, content: Say) -> None:
        for index, word in enumerate(content.text.split(" ")):
            piece = word if index == 0 else " " + word
            await self._send({"serverContent": {"modelTurn": {"role": "model", "parts": [{"text": piece}]}}})
            reply.said += piece
            await asyncio.sleep(0)  # let an interruption in between parts

    async def _stream_audio(self, reply: _Reply, content: Say) -> None:
        script, turn = self._script, reply.turn
        pcm = speech_pcm(content.text, script.ms_per_char, OUTPUT_RATE)
        step = script.chunk_ms * OUTPUT_RATE * 2 // 1000
        for start in range(0, len(pcm), step):
            await self._fault(turn, reply.audio_ms)
            chunk = pcm[start : start + step]
            part = {"inlineData": {"mimeType": OUTPUT_MIME, "data": base64.b64encode(chunk).decode("ascii")}}
            await self._send({"serverContent": {"modelTurn": {"role": "model", "parts": [part]}}})
            reply.audio_ms += len(chunk) * 1000 // (OUTPUT_RATE * 2)
            spoken = content.text[: reply.audio_ms // script.ms_per_char]
            if len(spoken) > len(reply.said):
                await self._transcribe_output(spoken[len(reply.said) :])
                reply.said = spoken
            await asyncio.sleep(len(chunk) / (OUTPUT_RATE * 2) * script.pace)
        if len(content.text) > len(reply.said):
            await self._transcribe_output(content.text[len(reply.said) :])
            reply.said = content.text

    async def _transcribe_output(self, text: str) -> None:
        if self.config.output_transcription:
            await self._send({"serverContent": {"outputTranscription": {"text": text}}})

    async def _fault(self, turn: Turn, sent_ms: int) -> None:
        if turn.drop_after_ms is not None and sent_ms >= turn.drop_after_ms:
            self._abort()
            raise ConnectionResetError("fault injection: connection dropped mid-reply")
        if turn.close_after_ms is not None and sent_ms >= turn.close_after_ms:
            await self._close(CLOSE_INTERNAL, DEADLINE_EXPIRED)
            raise ConnectionResetError("fault injection: deadline expired mid-reply")
        if turn.stall_after_ms is not None and sent_ms >= turn.stall_after_ms:
            await asyncio.Future()  # a stalled model: only an interruption ends it

    async def _end_turn(self, reply: _Reply) -> None:
        """turnComplete with the turn's usage, then the turn-boundary extras: a resumption handle,
        and the scheduled goAway."""
        self.conversation.add_text("model", reply.said)
        self.model_turns += 1
        await self._send({"serverContent": {"turnComplete": True}, "usageMetadata": self._usage(reply)})
        if self.config.resumption:
            handle = self._issue_handle(self.conversation.copy())
            await self._send({"sessionResumptionUpdate": {"newHandle": handle, "resumable": True}})
        if self._script.go_away_after_turns == self.model_turns:
            left = self._script.go_away_time_left_s
            await self._send({"goAway": {"timeLeft": duration_text(left)}})
            self._timers.append(asyncio.ensure_future(self._go_away(left)))

    async def _go_away(self, after_s: float) -> None:
        await asyncio.sleep(after_s)
        with contextlib.suppress(Exception):
            await self._close(1000, "GoAway")

    # ---- usage (invented numbers, real shape) -----------------------------------------------
    def _prompt_usage(self) -> JsonObject:
        conversation = self.conversation
        counts = {
            "TEXT": conversation.text_tokens + _tokens(self.config.instructions),
            "AUDIO": conversation.audio_ms * AUDIO_TOKENS_PER_S // 1000,
            self._script.frame_modality: conversation.frames * self._script.image_tokens,
        }
        return {modality: count for modality, count in counts.items() if count}

    def _usage(self, reply: _Reply) -> JsonObject:
        prompt = reply.prompt
        response = (
            {"AUDIO": reply.audio_ms * AUDIO_TOKENS_PER_S // 1000}
            if reply.audio_ms
            else {"TEXT": _tokens(reply.said)}
        )
        prompt_total, response_total = sum(prompt.values()), sum(response.values())
        return {
            "promptTokenCount": prompt_total,
            "responseTokenCount": response_total,
            "totalTokenCount": prompt_total + response_total,
            "promptTokensDetails": [{"modality": m, "tokenCount": n} for m, n in prompt.items()],
            "responseTokensDetails": [{"modality": m, "tokenCount": n} for m, n in response.items()],
        }


def _camel(name: str) -> str:
    head, *rest = name.split("_")
    return head + "".join(word.title() for word in rest)


def _tokens(text: str) -> int:
    return math.ceil(len(text) / 4)


def _content_text(content: JsonObject) -> str:
    parts = list_field(content, "parts", "content")
    return " ".join(
        str(part.get("text"))
        for part in parts
        if isinstance(part, dict) and isinstance(part.get("text"), str)
    )


def _function_names(setup: JsonObject) -> tuple[str, ...]:
    names: list[str] = []
    for tool in list_field(setup, "tools", "setup"):
        if not isinstance(tool, dict):
            raise WireError(f"{INVALID_ARGUMENT} 'setup.tools' holds Tool objects.")
        for declaration in list_field(tool, "functionDeclarations", "setup.tools"):
            name = (
                str_field(declaration, "name", "functionDeclarations")
                if isinstance(declaration, dict)
                else None
            )
            if not name:
                raise WireError(f"{INVALID_ARGUMENT} A function declaration needs a name.")
            names.append(name)
    return tuple(names)


def _non_blocking(setup: JsonObject) -> frozenset[str]:
    names: set[str] = set()
    for tool in list_field(setup, "tools", "setup"):
        for declaration in list_field(tool, "functionDeclarations", "setup.tools"):
            behavior = str_field(declaration, "behavior", "functionDeclarations") or "BLOCKING"
            if behavior not in ("BLOCKING", "NON_BLOCKING", "UNSPECIFIED"):
                raise WireError(f"{INVALID_ARGUMENT} Invalid value at 'functionDeclarations.behavior'.")
            if behavior == "NON_BLOCKING":
                names.add(str(declaration.get("name")))
    return frozenset(names)
