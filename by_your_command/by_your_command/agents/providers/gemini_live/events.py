"""Gemini Live server messages (the SDK's LiveServerMessage) → our ProviderEvents.

Gemini has no response or item ids: a "response" here is one model turn, from its first content to
`turnComplete`, and gets an id we invent (unique across sessions, so a cut named in one session is
never confused with a reply of the next). A toolCall ends its response (like an OpenAI function-call
response); the model's words after the toolResponse are a new one. A `turnComplete` right after a
toolCall closes nothing new. Usage may ride on any message: it is added to the open response, or to
the next one when it comes after a turnComplete.

Only fields both google-genai 2.33 and 3.x have are read (protocols.md B.6).
"""

from __future__ import annotations

import json
import re
import uuid
from collections import OrderedDict, deque
from typing import Final

from google.genai import types

from by_your_command.agents.events import (
    AssistantAudio,
    AssistantText,
    AssistantTranscript,
    Interrupted,
    ProviderEvent,
    ResponseDone,
    ResponseStatus,
    SessionEnding,
    ToolCall,
    ToolCallCancelled,
    Usage,
    UserTranscript,
)

OUTPUT_RATE: Final = 24_000  # Gemini Live's PCM out, unless the MIME type says otherwise
_RATE = re.compile(r"rate=(\d+)")
_REMEMBERED = 64  # cut responses and tool call names kept (bounded memory in long sessions)


def new_response_id() -> str:
    return f"gemini-resp-{uuid.uuid4().hex[:16]}"


def usage_from(meta: types.UsageMetadata | None) -> Usage:
    """Tokens by modality; IMAGE and VIDEO both count as image tokens (camera frames are billed,
    litellm#36886). What the details do not explain is counted as text, so totals match billing."""
    if meta is None:
        return Usage()
    given = _by_modality(meta.prompt_tokens_details)
    made = _by_modality(meta.response_tokens_details)
    prompt_total = (meta.prompt_token_count or 0) + (meta.tool_use_prompt_token_count or 0)
    in_text, in_audio = given.get("TEXT", 0), given.get("AUDIO", 0)
    in_image = given.get("IMAGE", 0) + given.get("VIDEO", 0)
    in_text += max(0, prompt_total - in_text - in_audio - in_image)
    out_audio = made.get("AUDIO", 0)
    out_text = made.get("TEXT", 0) + max(
        0, (meta.response_token_count or 0) - out_audio - made.get("TEXT", 0)
    )
    return Usage(
        input_text_tokens=in_text,
        input_audio_tokens=in_audio,
        input_image_tokens=in_image,
        cached_input_tokens=meta.cached_content_token_count or 0,
        output_text_tokens=out_text + (meta.thoughts_token_count or 0),  # thinking is billed as output
        output_audio_tokens=out_audio,
    )


def _by_modality(details: list[types.ModalityTokenCount] | None) -> dict[str, int]:
    counts: dict[str, int] = {}
    for detail in details or ():
        modality = detail.modality.value if detail.modality is not None else "TEXT"
        counts[modality] = counts.get(modality, 0) + (detail.token_count or 0)
    return counts


def _refusal(content: types.LiveServerContent) -> str:
    """Why the server ended a turn, when it says (`turnCompleteReason`: NEED_MORE_INPUT,
    RESPONSE_REJECTED, a safety reason); "" when it does not. google-genai 2.33 may lack the field."""
    reason = getattr(content, "turn_complete_reason", None)
    name = str(getattr(reason, "value", reason) or "")
    return "" if name in ("", "TURN_COMPLETE_REASON_UNSPECIFIED") else name


def seconds_left(time_left: str | None) -> float:
    """A protobuf Duration in JSON ("5s", "0.5s") → seconds (0 when absent or unreadable)."""
    if not time_left:
        return 0.0
    try:
        return max(0.0, float(time_left.rstrip("s")))
    except ValueError:
        return 0.0


class EventTranslator:
    def __init__(self, audio_out: bool, text_from_transcription: bool) -> None:
        self._audio_out = audio_out
        # A text-only agent on an audio-only model: the output transcription is the text reply.
        self._text_from_transcription = text_from_transcription
        self._response: str | None = None
        self._interrupted = False
        self._words: list[str] = []  # transcript (or text) of the open response
        self._heard: list[str] = []  # input transcription not yet reported
        self._usage = Usage()  # usage not yet attached to a ResponseDone
        self._after_tool_call = False
        self._cut: deque[str] = deque(maxlen=_REMEMBERED)
        self._call_names: OrderedDict[str, str] = OrderedDict()
        self.cancelled_calls: deque[str] = deque(maxlen=_REMEMBERED)

    @property
    def active_response(self) -> str | None:
        return self._response

    def mark_cut(self, response_id: str) -> None:
        """We interrupted this reply: its further audio is dropped, not played."""
        self._cut.append(response_id)

    def call_name(self, call_id: str) -> str | None:
        return self._call_names.get(call_id)

    def connection_lost(self, why: str = "connection_lost") -> list[ProviderEvent]:
        """The socket died (`why`: the close as the server gave it): end the reply in flight so the
        runtime can close its stream."""
        out = self._flush_heard()
        if self._response is not None:
            out.append(ResponseDone(self._response, ResponseStatus.FAILED, self._take_usage(), why))
            self._response = None
        return out

    def translate(self, message: types.LiveServerMessage) -> list[ProviderEvent]:
        out: list[ProviderEvent] = []
        if message.usage_metadata is not None:
            self._usage = self._usage + usage_from(message.usage_metadata)
        content = message.server_content
        if content is not None:
            out += self._content(content)
        if message.tool_call is not None:
            out += self._tool_call(message.tool_call)
        if message.tool_call_cancellation is not None:
            out += self._cancelled(message.tool_call_cancellation.ids or [])
        if message.go_away is not None:
            out.append(SessionEnding("goAway", seconds_left(message.go_away.time_left)))
        if content is not None and content.turn_complete:
            out += self._turn_complete(_refusal(content))
        return out

    # ---- pieces -----------------------------------------------------------------------------
    def _open(self) -> str:
        if self._response is None:
            self._response = new_response_id()
            self._interrupted = False
            self._words = []
            self._after_tool_call = False
        return self._response

    def _content(self, content: types.LiveServerContent) -> list[ProviderEvent]:
        out: list[ProviderEvent] = []
        heard = content.input_transcription
        if heard is not None and heard.text:
            self._heard.append(heard.text)
        if heard is not None and heard.finished:
            out += self._flush_heard()
        parts = content.model_turn.parts if content.model_turn is not None else None
        for part in parts or ():
            blob = part.inline_data
            if blob is not None and blob.data and (blob.mime_type or "").startswith("audio/pcm"):
                out += self._audio(blob.data, blob.mime_type or "")
            elif part.text and not part.thought:
                response = self._open()
                self._words.append(part.text)
                out.append(AssistantText(response, response, part.text, final=False))
        said = content.output_transcription
        if said is not None and said.text:
            response = self._open()
            self._words.append(said.text)
            kind = AssistantText if self._text_from_transcription else AssistantTranscript
            out.append(kind(response, response, said.text, final=False))
        if content.interrupted and self._response is not None:
            self._interrupted = True
            out.append(Interrupted(self._response))
        return out

    def _audio(self, data: bytes, mime_type: str) -> list[ProviderEvent]:
        response = self._open()
        pcm = data[: len(data) - len(data) % 2]  # whole int16 samples only
        if not pcm or not self._audio_out or self._text_from_transcription or response in self._cut:
            return []
        match = _RATE.search(mime_type)
        return [AssistantAudio(response, response, pcm, int(match.group(1)) if match else OUTPUT_RATE)]

    def _tool_call(self, call: types.LiveServerToolCall) -> list[ProviderEvent]:
        response = self._open()
        out: list[ProviderEvent] = []
        for function in call.function_calls or ():
            call_id = function.id or f"call-{uuid.uuid4().hex[:12]}"
            name = function.name or ""
            self._call_names[call_id] = name
            while len(self._call_names) > _REMEMBERED:
                self._call_names.popitem(last=False)
            out.append(ToolCall(response, call_id, name, json.dumps(function.args or {})))
        # The model waits for the results (BLOCKING): what it says next is a new response.
        out += self._close(ResponseStatus.COMPLETED)
        self._after_tool_call = True
        return out

    def _cancelled(self, ids: list[str]) -> list[ProviderEvent]:
        """Calls the server withdrew (the user cut in): their results must never be sent."""
        withdrawn = tuple(dict.fromkeys(call_id for call_id in ids[:_REMEMBERED] if call_id))
        self.cancelled_calls.extend(withdrawn)
        return [ToolCallCancelled(withdrawn)] if withdrawn else []

    def _turn_complete(self, refusal: str) -> list[ProviderEvent]:
        out = self._flush_heard()
        if self._response is not None:
            out += self._close(ResponseStatus.CANCELLED if self._interrupted else ResponseStatus.COMPLETED)
        elif self._after_tool_call:
            self._after_tool_call = False  # the tool-calling turn's own end: already reported
        elif refusal:  # the model declined the turn (e.g. it held no speech): it failed, now
            reason = f"the model gave no reply ({refusal})"
            out.append(ResponseDone(new_response_id(), ResponseStatus.FAILED, self._take_usage(), reason))
        else:  # a turn without content still ends the user's turn
            out.append(ResponseDone(new_response_id(), ResponseStatus.COMPLETED, self._take_usage()))
        return out

    def _close(self, status: ResponseStatus) -> list[ProviderEvent]:
        response = self._response
        if response is None:
            return []
        out: list[ProviderEvent] = []
        text = "".join(self._words)
        if text:
            spoken = self._audio_out and not self._text_from_transcription
            kind = AssistantTranscript if spoken else AssistantText
            out.append(kind(response, response, text, final=True))
        reason = "interrupted" if status is ResponseStatus.CANCELLED else ""
        out.append(ResponseDone(response, status, self._take_usage(), reason))
        self._response = None
        self._words = []
        return out

    def _flush_heard(self) -> list[ProviderEvent]:
        if not self._heard:
            return []
        text, self._heard = "".join(self._heard).strip(), []
        return [UserTranscript(text)]

    def _take_usage(self) -> Usage:
        usage, self._usage = self._usage, Usage()
        return usage
