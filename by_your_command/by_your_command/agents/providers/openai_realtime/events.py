"""OpenAI Realtime server events (the SDK's typed models) → our ProviderEvents.

It also keeps the bookkeeping the provider needs for a correct barge-in: how much audio arrived for
each assistant item (a truncate beyond that is a fatal server error, pipecat#2106), which response
is active, and which responses we cancelled (their late deltas are dropped, not played).
"""

from __future__ import annotations

import base64
import binascii
from collections import OrderedDict, deque
from typing import Final

from openai.types.realtime import (
    ConversationItemInputAudioTranscriptionCompletedEvent,
    ConversationItemInputAudioTranscriptionFailedEvent,
    RealtimeErrorEvent,
    RealtimeResponseUsage,
    ResponseAudioDeltaEvent,
    ResponseAudioTranscriptDeltaEvent,
    ResponseAudioTranscriptDoneEvent,
    ResponseCreatedEvent,
    ResponseDoneEvent,
    ResponseFunctionCallArgumentsDoneEvent,
    ResponseTextDeltaEvent,
    ResponseTextDoneEvent,
)
from openai.types.realtime.conversation_item_input_audio_transcription_completed_event import (
    UsageTranscriptTextUsageTokens,
)

from by_your_command.agents.events import (
    AssistantAudio,
    AssistantText,
    AssistantTranscript,
    ProviderError,
    ProviderEvent,
    ResponseDone,
    ResponseStatus,
    SessionEnding,
    ToolCall,
    Usage,
    UserTranscript,
)
from by_your_command.agents.providers.openai_realtime.errors import provider_error

SAMPLE_RATE: Final = 24_000  # the Realtime API's PCM, in and out
BYTES_PER_MS = SAMPLE_RATE * 2 // 1000
_REMEMBERED = 64  # items/responses kept for bookkeeping (bounded memory in long sessions)


def usage_from(usage: RealtimeResponseUsage | None) -> Usage:
    if usage is None:
        return Usage()
    given = usage.input_token_details
    made = usage.output_token_details
    return Usage(
        input_text_tokens=(given.text_tokens or 0) if given else 0,
        input_audio_tokens=(given.audio_tokens or 0) if given else 0,
        input_image_tokens=(given.image_tokens or 0) if given else 0,
        cached_input_tokens=(given.cached_tokens or 0) if given else 0,
        output_text_tokens=(made.text_tokens or 0) if made else 0,
        output_audio_tokens=(made.audio_tokens or 0) if made else 0,
    )


def _transcription_usage(event: ConversationItemInputAudioTranscriptionCompletedEvent) -> Usage:
    usage = event.usage
    if not isinstance(usage, UsageTranscriptTextUsageTokens):
        return Usage()  # billed by duration: no tokens to count
    details = usage.input_token_details
    audio = details.audio_tokens if details and details.audio_tokens is not None else usage.input_tokens
    text = details.text_tokens or 0 if details else 0
    return Usage(input_audio_tokens=audio, input_text_tokens=text, output_text_tokens=usage.output_tokens)


_STATUSES = {status.value: status for status in ResponseStatus}


class EventTranslator:
    def __init__(self) -> None:
        self._audio_bytes: OrderedDict[str, int] = OrderedDict()  # item id → bytes received
        self._cancelled: deque[str] = deque(maxlen=_REMEMBERED)
        self.active_response: str | None = None

    def audio_received_ms(self, item_id: str) -> int:
        return self._audio_bytes.get(item_id, 0) // BYTES_PER_MS

    def mark_cancelled(self, response_id: str) -> None:
        self._cancelled.append(response_id)

    def _wanted(self, response_id: str) -> bool:
        return response_id not in self._cancelled

    def _count_audio(self, item_id: str, size: int) -> None:
        self._audio_bytes[item_id] = self._audio_bytes.pop(item_id, 0) + size
        while len(self._audio_bytes) > _REMEMBERED:
            self._audio_bytes.popitem(last=False)

    def connection_lost(self, why: str = "connection_lost") -> list[ProviderEvent]:
        """The socket died (`why`: the close as the server gave it): end the reply in flight so the
        runtime can close its stream."""
        if self.active_response is None:
            return []
        done = ResponseDone(self.active_response, ResponseStatus.FAILED, reason=why)
        self.active_response = None
        return [done]

    def translate(self, event: object) -> list[ProviderEvent]:
        if isinstance(event, ResponseAudioDeltaEvent):
            return self._audio(event)
        if isinstance(event, ResponseAudioTranscriptDeltaEvent | ResponseAudioTranscriptDoneEvent):
            if not self._wanted(event.response_id):
                return []
            final = isinstance(event, ResponseAudioTranscriptDoneEvent)
            text = event.transcript if isinstance(event, ResponseAudioTranscriptDoneEvent) else event.delta
            return [AssistantTranscript(event.response_id, event.item_id, text, final)]
        if isinstance(event, ResponseTextDeltaEvent | ResponseTextDoneEvent):
            if not self._wanted(event.response_id):
                return []
            final = isinstance(event, ResponseTextDoneEvent)
            text = event.text if isinstance(event, ResponseTextDoneEvent) else event.delta
            return [AssistantText(event.response_id, event.item_id, text, final)]
        if isinstance(event, ResponseFunctionCallArgumentsDoneEvent):
            if not self._wanted(event.response_id):
                return []
            return [ToolCall(event.response_id, event.call_id, event.name, event.arguments)]
        if isinstance(event, ConversationItemInputAudioTranscriptionCompletedEvent):
            return [UserTranscript(event.transcript, event.item_id, _transcription_usage(event))]
        if isinstance(event, ConversationItemInputAudioTranscriptionFailedEvent):
            message = event.error.message or "input transcription failed"
            return [ProviderError(event.error.code or "transcription_failed", message)]
        if isinstance(event, ResponseCreatedEvent):
            self.active_response = event.response.id
            return []
        if isinstance(event, ResponseDoneEvent):
            return self._done(event)
        if isinstance(event, RealtimeErrorEvent):
            return self._error(event)
        return []

    def _audio(self, event: ResponseAudioDeltaEvent) -> list[ProviderEvent]:
        try:
            pcm = base64.b64decode(event.delta, validate=True)
        except (binascii.Error, ValueError):
            return [ProviderError("invalid_server_event", "audio delta that is not base64: dropped")]
        pcm = pcm[: len(pcm) - len(pcm) % 2]  # whole int16 samples only
        self._count_audio(event.item_id, len(pcm))
        if not pcm or not self._wanted(event.response_id):
            return []
        return [AssistantAudio(event.response_id, event.item_id, pcm, SAMPLE_RATE)]

    def _done(self, event: ResponseDoneEvent) -> list[ProviderEvent]:
        response = event.response
        response_id = response.id or ""
        if response_id == self.active_response:
            self.active_response = None
        details = response.status_details
        out: list[ProviderEvent] = []
        reason = ""
        if details is not None and details.error is not None:
            reason = details.error.code or details.error.type or "failed"
            mapped = provider_error(details.error.code, details.error.message or "the response failed")
            if mapped is not None:
                out.append(mapped)
        elif details is not None and details.reason:
            reason = details.reason
        status = _STATUSES.get(response.status or "", ResponseStatus.INCOMPLETE)
        out.append(ResponseDone(response_id, status, usage_from(response.usage), reason))
        return out

    @staticmethod
    def _error(event: RealtimeErrorEvent) -> list[ProviderEvent]:
        error = event.error
        if error.code == "session_expired":
            # The server closes right after: the runtime rotates to a new session.
            return [SessionEnding(error.message, 0.0)]
        mapped = provider_error(error.code, error.message)
        return [] if mapped is None else [mapped]
