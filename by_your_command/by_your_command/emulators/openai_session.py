"""One OpenAI Realtime (GA) session of the emulator: the rules the real server enforces, replies from
the script. The server module owns the socket; this class only sees parsed client events.

Faithful (protocols.md C.4): event names, nesting, id linkage, error envelope and codes, the 100 ms
commit minimum, one active response, `response.done` last, truncation bounded by the audio
produced. Invented: ids, timing, token counts, transcripts, the cancel-time `.done` cascade.
Not emulated: server/semantic VAD (commit manually), MCP, `conversation.item.retrieve` audio.
"""

from __future__ import annotations

import asyncio
import base64
import copy
import math
import time
from collections import OrderedDict, deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

from by_your_command.emulators.openai_script import CallTool, Say, Script, Silence, Turn
from by_your_command.emulators.openai_validation import (
    AUDIO_INPUT_KEYS,
    AUDIO_OUTPUT_KEYS,
    RESPONSE_KEYS,
    SESSION_KEYS,
    check_keys,
    validate_item,
)
from by_your_command.emulators.openai_wire import (
    ClientEventError,
    JsonObject,
    decode_pcm,
    error_event,
    field_int,
    field_object,
    field_str,
    new_id,
    required_str,
)
from by_your_command.emulators.synthetic_speech import BYTES_PER_MS, OUTPUT_RATE, speech_pcm

MIN_COMMIT_MS = 100


@dataclass(frozen=True)
class SessionLimits:
    max_buffer_ms: int = 15 * 60 * 1000  # uncommitted input audio (bounded memory)
    max_items: int = 2048  # conversation items; the oldest go first, as with truncation "auto"


class ScriptCursor:
    """The script's turns, consumed one per response across every connection of one emulator."""

    def __init__(self, script: Script) -> None:
        self.script = script
        self._turns: deque[Turn] = deque(script.turns)
        # A tool call's `then` answers the first response after its function_call_output (other
        # turns may come between: a robot action runs while the conversation goes on).
        self._unbound: Say | None = None  # the call being streamed, before its call_id exists
        self._follow_ups: dict[str, Say] = {}  # by call_id, until its output comes
        self._answered: deque[Say] = deque()  # outputs came: these answer the next responses

    def heard(self) -> str:
        if not self._answered and self._turns:
            return self._turns[0].heard
        return self.script.default_heard

    def next_turn(self) -> Turn:
        if self._answered:
            return Turn(self._answered.popleft())
        turn = self._turns.popleft() if self._turns else Turn(self.script.default_reply)
        if isinstance(turn.reply, CallTool):
            self._unbound = turn.reply.then
        return turn

    def bind(self, call_id: str) -> None:
        if self._unbound is not None:
            self._follow_ups[call_id], self._unbound = self._unbound, None

    def output_for(self, call_id: str) -> None:
        follow_up = self._follow_ups.pop(call_id, None)
        if follow_up is not None:
            self._answered.append(follow_up)


@dataclass
class _Item:
    data: JsonObject
    audio_ms: int = 0  # audio in this item (user input or assistant output)


@dataclass
class _Response:
    data: JsonObject
    turn: Turn
    audio: bool
    in_conversation: bool
    task: asyncio.Task[None] | None = None
    item: JsonObject | None = None
    said: str = ""
    audio_ms: int = 0
    part_open: bool = False
    finishing: bool = False
    usage_input: JsonObject = field(default_factory=dict)


def _tokens(text: str) -> int:
    return math.ceil(len(text) / 4)


class OpenAIRealtimeSession:
    def __init__(
        self,
        send: Callable[[JsonObject], Awaitable[None]],
        abort: Callable[[], None],
        cursor: ScriptCursor,
        model: str,
        limits: SessionLimits = SessionLimits(),
    ) -> None:
        self._send_raw, self._abort = send, abort
        self._cursor, self._script, self._limits = cursor, cursor.script, limits
        self.model = model
        self._buffer = bytearray()
        self._items: OrderedDict[str, _Item] = OrderedDict()
        self._response: _Response | None = None
        self._previous_input_tokens = 0
        self.session = self._default_session(model)

    # ---- plumbing ---------------------------------------------------------------------------
    async def send(self, type_: str, **payload: Any) -> None:
        await self._send_raw({"type": type_, "event_id": new_id("event"), **payload})

    async def start(self) -> None:
        await self.send("session.created", session=self.session)

    async def close(self) -> None:
        response = self._response
        if response and response.task and not response.task.done():
            response.task.cancel()
            await asyncio.gather(response.task, return_exceptions=True)

    @staticmethod
    def _default_session(model: str) -> JsonObject:
        pcm = {"type": "audio/pcm", "rate": OUTPUT_RATE}
        vad = {
            "type": "server_vad",
            "threshold": 0.5,
            "prefix_padding_ms": 300,
            "silence_duration_ms": 500,
            "create_response": True,
            "interrupt_response": True,
        }
        return {
            "type": "realtime",
            "object": "realtime.session",
            "id": new_id("sess"),
            "model": model,
            "output_modalities": ["audio"],
            "instructions": "",
            "tools": [],
            "tool_choice": "auto",
            "max_output_tokens": "inf",
            "tracing": None,
            "truncation": "auto",
            "prompt": None,
            "expires_at": int(time.time()) + 3600,
            "include": None,
            "audio": {
                "input": {
                    "format": pcm,
                    "transcription": None,
                    "noise_reduction": None,
                    "turn_detection": vad,
                },
                "output": {"format": pcm, "voice": "marin", "speed": 1.0},
            },
        }

    # ---- dispatch ---------------------------------------------------------------------------
    async def handle(self, event: JsonObject) -> None:
        """Apply one parsed client event; refusals become `error` events (the session stays open)."""
        handlers: dict[str, Callable[[JsonObject], Awaitable[None]]] = {
            "session.update": self._session_update,
            "input_audio_buffer.append": self._append,
            "input_audio_buffer.commit": self._commit,
            "input_audio_buffer.clear": self._clear,
            "conversation.item.create": self._item_create,
            "conversation.item.delete": self._item_delete,
            "conversation.item.retrieve": self._item_retrieve,
            "conversation.item.truncate": self._item_truncate,
            "response.create": self._response_create,
            "response.cancel": self._response_cancel,
        }
        kind = event["type"]
        try:
            handler = handlers.get(kind)
            if handler is None:
                raise ClientEventError(
                    "invalid_value", f"Invalid value: '{kind}'. Unknown event type.", "type"
                )
            await handler(event)
        except ClientEventError as error:
            await self._send_raw(error_event(error.code, error.message, error.param, event.get("event_id")))

    # ---- session ----------------------------------------------------------------------------
    async def _session_update(self, event: JsonObject) -> None:
        update = field_object(event, "session", "session")
        if update.get("type") is None:
            raise ClientEventError(
                "missing_required_parameter", "Missing required parameter: 'session.type'.", "session.type"
            )
        if update["type"] != "realtime":
            raise ClientEventError(
                "invalid_value",
                "Invalid value for 'session.type': this emulator serves 'realtime'.",
                "session.type",
            )
        check_keys(update, SESSION_KEYS, "session")
        modalities = update.get("output_modalities")
        if modalities is not None and modalities not in (["audio"], ["text"]):
            raise ClientEventError(
                "invalid_value",
                "Invalid value for 'session.output_modalities': use ['audio'] or ['text'].",
                "session.output_modalities",
            )
        audio = field_object(update, "audio", "session.audio", required=False)
        check_keys(audio, {"input", "output"}, "session.audio")
        check_keys(
            field_object(audio, "input", "session.audio.input", required=False),
            AUDIO_INPUT_KEYS,
            "session.audio.input",
        )
        check_keys(
            field_object(audio, "output", "session.audio.output", required=False),
            AUDIO_OUTPUT_KEYS,
            "session.audio.output",
        )
        if isinstance(update.get("tools"), list):
            for index, tool in enumerate(update["tools"]):
                where = f"session.tools[{index}]"
                if not isinstance(tool, dict) or tool.get("type") not in ("function", "mcp"):
                    raise ClientEventError(
                        "invalid_value", f"Invalid value for '{where}.type'.", f"{where}.type"
                    )
        _deep_merge(self.session, update)
        await self.send("session.updated", session=self.session)

    # ---- input audio ------------------------------------------------------------------------
    async def _append(self, event: JsonObject) -> None:
        pcm = decode_pcm(required_str(event, "audio", "audio"), "audio")
        if (len(self._buffer) + len(pcm)) // BYTES_PER_MS > self._limits.max_buffer_ms:
            raise ClientEventError(
                "input_audio_buffer_too_large",
                f"The input audio buffer holds at most {self._limits.max_buffer_ms} ms; commit or clear it.",
            )
        self._buffer += pcm

    async def _clear(self, _: JsonObject) -> None:
        self._buffer.clear()
        await self.send("input_audio_buffer.cleared")

    async def _commit(self, _: JsonObject) -> None:
        buffered_ms = len(self._buffer) / BYTES_PER_MS
        if buffered_ms < MIN_COMMIT_MS:
            raise ClientEventError(
                "input_audio_buffer_commit_empty",
                "Error committing input audio buffer: buffer too small. Expected at least "
                f"{MIN_COMMIT_MS}ms of audio, but buffer only has {buffered_ms:.2f}ms of audio.",
            )
        item_id = new_id("item")
        previous = self._last_item_id()
        await self.send("input_audio_buffer.committed", previous_item_id=previous, item_id=item_id)
        item = {
            "id": item_id,
            "object": "realtime.item",
            "type": "message",
            "role": "user",
            "status": "completed",
            "content": [{"type": "input_audio", "transcript": None}],
        }
        self._add_item(_Item(item, int(buffered_ms)))
        self._buffer.clear()
        await self.send("conversation.item.added", previous_item_id=previous, item=item)
        await self.send("conversation.item.done", previous_item_id=previous, item=item)
        if self.session["audio"]["input"].get("transcription"):
            await self._transcribe(item, int(buffered_ms))

    async def _transcribe(self, item: JsonObject, audio_ms: int) -> None:
        heard = self._cursor.heard()
        words = heard.split(" ")
        for index, word in enumerate(words):
            await self.send(
                "conversation.item.input_audio_transcription.delta",
                item_id=item["id"],
                content_index=0,
                delta=word if index == 0 else " " + word,
            )
        item["content"][0]["transcript"] = heard
        audio_tokens = max(1, audio_ms // 100)
        await self.send(
            "conversation.item.input_audio_transcription.completed",
            item_id=item["id"],
            content_index=0,
            transcript=heard,
            usage={
                "type": "tokens",
                "input_tokens": audio_tokens,
                "output_tokens": _tokens(heard),
                "total_tokens": audio_tokens + _tokens(heard),
                "input_token_details": {"audio_tokens": audio_tokens, "text_tokens": 0},
            },
        )

    # ---- conversation items -----------------------------------------------------------------
    def _last_item_id(self) -> str | None:
        return next(reversed(self._items), None)

    def _add_item(self, item: _Item) -> None:
        self._items[item.data["id"]] = item
        while len(self._items) > self._limits.max_items:
            self._items.popitem(last=False)

    async def _item_create(self, event: JsonObject) -> None:
        item = copy.deepcopy(field_object(event, "item", "item"))
        validate_item(item)
        item_id = field_str(item, "id", "item.id", required=False) or new_id("item")
        if len(item_id) > 32:
            raise ClientEventError("invalid_value", "Invalid 'item.id': at most 32 characters.", "item.id")
        if item_id in self._items:
            raise ClientEventError("invalid_value", f"Item with id '{item_id}' already exists.", "item.id")
        previous = field_str(event, "previous_item_id", "previous_item_id", required=False)
        if previous is not None and previous != "root" and previous not in self._items:
            raise ClientEventError(
                "item_not_found", f"Item with item_id not found: {previous}", "previous_item_id"
            )
        item.update(id=item_id, object="realtime.item", status="completed")
        if item.get("type") == "function_call_output":
            self._cursor.output_for(str(item.get("call_id")))
        audio_ms = sum(
            len(decode_pcm(part["audio"], "item.content.audio")) // BYTES_PER_MS
            for part in item.get("content", [])
            if part.get("type") == "input_audio"
        )
        previous = previous or self._last_item_id()
        self._add_item(_Item(item, audio_ms))
        await self.send("conversation.item.added", previous_item_id=previous, item=item)
        await self.send("conversation.item.done", previous_item_id=previous, item=item)

    def _existing(self, event: JsonObject) -> tuple[str, _Item]:
        item_id = required_str(event, "item_id", "item_id")
        item = self._items.get(item_id)
        if item is None:
            raise ClientEventError("item_not_found", f"Item with item_id not found: {item_id}", "item_id")
        return item_id, item

    async def _item_delete(self, event: JsonObject) -> None:
        item_id, _ = self._existing(event)
        del self._items[item_id]
        await self.send("conversation.item.deleted", item_id=item_id)

    async def _item_retrieve(self, event: JsonObject) -> None:
        _, item = self._existing(event)
        await self.send("conversation.item.retrieved", item=item.data)

    async def _item_truncate(self, event: JsonObject) -> None:
        item_id, item = self._existing(event)
        content_index = field_int(event, "content_index", "content_index")
        end_ms = field_int(event, "audio_end_ms", "audio_end_ms")
        if item.data.get("role") != "assistant" or content_index != 0:
            raise ClientEventError(
                "invalid_value", "Only assistant message audio can be truncated.", "item_id"
            )
        if end_ms < 0 or end_ms > item.audio_ms:
            # The real server's words (pipecat#2106): it treats this as a fatal client bug.
            raise ClientEventError(
                "invalid_value",
                f"Audio content of {item.audio_ms} ms is already shorter than {end_ms} ms",
                "audio_end_ms",
            )
        item.audio_ms = end_ms
        for part in item.data.get("content", []):
            if part.get("type") == "output_audio" and isinstance(part.get("transcript"), str):
                part["transcript"] = part["transcript"][: end_ms // self._script.ms_per_char]
        await self.send(
            "conversation.item.truncated", item_id=item_id, content_index=content_index, audio_end_ms=end_ms
        )

    # ---- responses --------------------------------------------------------------------------
    def _active(self) -> _Response | None:
        response = self._response
        return response if response and not response.finishing else None

    async def _response_create(self, event: JsonObject) -> None:
        params = field_object(event, "response", "response", required=False)
        check_keys(params, RESPONSE_KEYS, "response")
        conversation = params.get("conversation", "auto")
        if conversation not in ("auto", "none"):
            raise ClientEventError(
                "invalid_value", "Invalid value for 'response.conversation'.", "response.conversation"
            )
        in_conversation = conversation == "auto"
        if in_conversation and self._response is not None:
            raise ClientEventError(
                "conversation_already_has_active_response",
                "Conversation already has an active response in progress: "
                f"{self._response.data['id']}. "
                "Wait until the response is finished before creating a new one.",
            )
        modalities = params.get("output_modalities") or self.session["output_modalities"]
        turn = self._cursor.next_turn()
        reply = turn.reply
        audio = "audio" in modalities and not (isinstance(reply, Say) and reply.modality == "text")
        data: JsonObject = {
            "id": new_id("resp"),
            "object": "realtime.response",
            "status": "in_progress",
            "status_details": None,
            "output": [],
            "conversation_id": "conv_emulated" if in_conversation else None,
            "output_modalities": ["audio"] if audio else ["text"],
            "max_output_tokens": params.get("max_output_tokens", "inf"),
            "audio": {"output": self.session["audio"]["output"]},
            "usage": None,
            "metadata": params.get("metadata"),
        }
        response = _Response(data, turn, audio, in_conversation, usage_input=self._input_usage())
        if in_conversation:
            self._response = response
        # Sent before the reply task starts, so a cancel right behind still finds it announced.
        await self.send("response.created", response=copy.deepcopy(data))
        response.task = asyncio.create_task(self._run_response(response))

    async def _response_cancel(self, event: JsonObject) -> None:
        wanted = field_str(event, "response_id", "response_id", required=False)
        response = self._active()
        if response is None or (wanted is not None and wanted != response.data["id"]):
            raise ClientEventError(
                "response_cancel_not_active", "Cancellation failed: no active response found"
            )
        assert response.task is not None
        response.task.cancel()
        await asyncio.gather(response.task, return_exceptions=True)
        if not response.finishing:  # cancelled before its task ever ran: nothing caught it there
            response.finishing = True
            await self._finish(response, "cancelled", "client_cancelled", None)

    async def _run_response(self, response: _Response) -> None:
        status, reason, error = "completed", None, None
        try:
            await self.send(
                "rate_limits.updated",
                rate_limits=[
                    {"name": "requests", "limit": 10_000, "remaining": 9_999, "reset_seconds": 0.006},
                    {"name": "tokens", "limit": 2_000_000, "remaining": 1_990_000, "reset_seconds": 0.3},
                ],
            )
            if self._script.known_models and self.model not in self._script.known_models:
                # What the real server does for a model the key cannot use (openai-realtime-console#561).
                status = "failed"
                error = {
                    "type": "invalid_request_error",
                    "code": "model_not_found",
                    "message": f"The model `{self.model}` does not exist or you do not have access to it.",
                }
            elif isinstance(response.turn.reply, CallTool):
                await self._stream_tool_call(response, response.turn.reply)
            elif isinstance(response.turn.reply, Silence):
                await asyncio.Future()  # never answers; only a cancel ends it
            else:
                await self._stream_words(response, response.turn.reply.text, response.turn)
        except asyncio.CancelledError:
            status, reason = "cancelled", "client_cancelled"
        except ConnectionResetError:
            return  # the fault injection dropped the connection
        response.finishing = True
        await self._finish(response, status, reason, error)

    async def _add_output_item(self, response: _Response, item: JsonObject) -> None:
        response.item = item
        previous = self._last_item_id()
        if response.in_conversation:
            self._add_item(_Item(item))
        await self.send(
            "response.output_item.added", response_id=response.data["id"], output_index=0, item=item
        )
        await self.send("conversation.item.added", previous_item_id=previous, item=item)

    async def _stream_tool_call(self, response: _Response, call: CallTool) -> None:
        item = {
            "id": new_id("item"),
            "object": "realtime.item",
            "type": "function_call",
            "status": "in_progress",
            "call_id": new_id("call"),
            "name": call.name,
            "arguments": "",
        }
        self._cursor.bind(item["call_id"])
        await self._add_output_item(response, item)
        ids = {"response_id": response.data["id"], "item_id": item["id"], "output_index": 0}
        await self.send(
            "response.function_call_arguments.delta", **ids, call_id=item["call_id"], delta=call.arguments
        )
        item["arguments"] = call.arguments
        await self.send(
            "response.function_call_arguments.done",
            **ids,
            call_id=item["call_id"],
            name=call.name,
            arguments=call.arguments,
        )
        response.said = call.arguments

    async def _stream_words(self, response: _Response, text: str, turn: Turn) -> None:
        item = {
            "id": new_id("item"),
            "object": "realtime.item",
            "type": "message",
            "role": "assistant",
            "status": "in_progress",
            "content": [],
        }
        await self._add_output_item(response, item)
        ids = {
            "response_id": response.data["id"],
            "item_id": item["id"],
            "output_index": 0,
            "content_index": 0,
        }
        part = {"type": "audio", "transcript": ""} if response.audio else {"type": "text", "text": ""}
        await self.send("response.content_part.added", **ids, part=part)
        response.part_open = True
        if not response.audio:
            for index, word in enumerate(text.split(" ")):
                delta = word if index == 0 else " " + word
                response.said += delta
                await self.send("response.output_text.delta", **ids, delta=delta)
            return
        ms_per_char, delta_ms = self._script.ms_per_char, self._script.delta_ms
        pcm = speech_pcm(text, ms_per_char)
        step = delta_ms * BYTES_PER_MS
        for start in range(0, len(pcm), step):
            for fault_ms, fault in ((turn.drop_after_ms, "drop"), (turn.stall_after_ms, "stall")):
                if fault_ms is not None and response.audio_ms >= fault_ms:
                    if fault == "drop":
                        self._abort()
                        raise ConnectionResetError("fault injection: connection dropped mid-reply")
                    await asyncio.Future()  # a stalled model: only a cancel ends it
            chunk = pcm[start : start + step]
            await self.send("response.output_audio.delta", **ids, delta=base64.b64encode(chunk).decode())
            response.audio_ms += len(chunk) // BYTES_PER_MS
            self._record_audio(response)
            spoken = text[: response.audio_ms // ms_per_char]
            if len(spoken) > len(response.said):
                await self.send(
                    "response.output_audio_transcript.delta", **ids, delta=spoken[len(response.said) :]
                )
                response.said = spoken
            if self._script.pace > 0:
                await asyncio.sleep(len(chunk) / BYTES_PER_MS / 1000 * self._script.pace)
            else:
                await asyncio.sleep(0)  # let the client's cancel in between deltas
        if len(text) > len(response.said):
            await self.send("response.output_audio_transcript.delta", **ids, delta=text[len(response.said) :])
            response.said = text

    def _record_audio(self, response: _Response) -> None:
        assert response.item is not None
        stored = self._items.get(response.item["id"])
        if stored is not None:
            stored.audio_ms = response.audio_ms

    async def _finish(
        self, response: _Response, status: str, reason: str | None, error: JsonObject | None
    ) -> None:
        data, item = response.data, response.item
        if item is not None:
            ids = {"response_id": data["id"], "item_id": item["id"], "output_index": 0}
            if response.part_open:
                key = "transcript" if response.audio else "text"
                if response.audio:
                    await self.send("response.output_audio.done", **ids, content_index=0)
                    await self.send(
                        "response.output_audio_transcript.done",
                        **ids,
                        content_index=0,
                        transcript=response.said,
                    )
                else:
                    await self.send("response.output_text.done", **ids, content_index=0, text=response.said)
                part_type = "audio" if response.audio else "text"
                await self.send(
                    "response.content_part.done",
                    **ids,
                    content_index=0,
                    part={"type": part_type, key: response.said},
                )
                item["content"] = [{"type": f"output_{part_type}", key: response.said}]
            item["status"] = "completed" if status == "completed" else "incomplete"
            await self.send("response.output_item.done", response_id=data["id"], output_index=0, item=item)
            await self.send("conversation.item.done", previous_item_id=None, item=item)
            data["output"] = [item]
        data["status"] = status
        if error is not None:
            data["status_details"] = {"type": "failed", "error": error}
        elif reason is not None:
            data["status_details"] = {"type": status, "reason": reason}
        data["usage"] = self._usage(response)
        if self._response is response:
            self._response = None
        await self.send("response.done", response=data)

    # ---- usage (invented numbers, real shape) -------------------------------------------------
    def _input_usage(self) -> JsonObject:
        text = _tokens(str(self.session.get("instructions") or ""))
        audio = image = 0
        for item in self._items.values():
            audio += item.audio_ms // 100
            for part in item.data.get("content", []):
                kind = part.get("type")
                if kind == "input_image":
                    image += self._script.image_tokens
                elif kind in ("input_text", "output_text"):
                    text += _tokens(str(part.get("text", "")))
                elif kind == "output_audio":
                    text += _tokens(str(part.get("transcript") or ""))
            text += _tokens(str(item.data.get("arguments", "")) + str(item.data.get("output", "")))
        total = text + audio + image
        cached = min(self._previous_input_tokens, total) // 64 * 64  # the cache works in 64-token steps
        self._previous_input_tokens = total
        return {
            "text_tokens": text,
            "audio_tokens": audio,
            "image_tokens": image,
            "cached_tokens": cached,
            "cached_tokens_details": {"text_tokens": min(cached, text), "audio_tokens": 0, "image_tokens": 0},
        }

    def _usage(self, response: _Response) -> JsonObject:
        details = response.usage_input
        input_tokens = details["text_tokens"] + details["audio_tokens"] + details["image_tokens"]
        out_audio = response.audio_ms // 50
        out_text = _tokens(response.said)
        return {
            "total_tokens": input_tokens + out_audio + out_text,
            "input_tokens": input_tokens,
            "output_tokens": out_audio + out_text,
            "input_token_details": details,
            "output_token_details": {"text_tokens": out_text, "audio_tokens": out_audio},
        }


def _deep_merge(target: JsonObject, update: JsonObject) -> None:
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(target.get(key), dict):
            _deep_merge(target[key], value)
        else:
            target[key] = copy.deepcopy(value)
