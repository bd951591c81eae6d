"""GPT-Live server events (the SDK's typed models) → our ProviderEvents.

GPT-Live has no responses: the model talks when it decides to, and its output audio and transcript
deltas carry no response or item id, and no event marks the end of what it says. The runtime
counts replies, so this translator makes them: a reply starts with the first output (audio,
transcript or a delegation) after a quiet spell and ends once the output has been quiet for
`reply_end_gap_s` (`tick` ends it; the provider calls it when `deadline` passes). The ids are ours.

No event says "the model stopped because the user spoke" either. The model streams its voice at
about real time, so a reply whose output stops for `yield_gap_s` after the user began speaking
while it talked (`user_speech`, from the audio we sent) yielded to the user: `Interrupted` at once
(the runtime cuts what the player still holds), then `ResponseDone(cancelled)`. A heuristic,
documented as such (docs/gpt_live.md).

Billing: `session.usage.updated` carries the session's total seconds; each increase is reported as
a `UsageReport` (`Usage.session_s`), so the runtime sums it like tokens.

A client delegation names no function and no arguments (the task is in the conversation): it
becomes a `ToolCall` of `delegation_tool` whose command is what the user said since the previous
delegation: the words the reply it belongs to answers, and any heard since.
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import uuid
from collections import Counter
from dataclasses import dataclass, field
from typing import Final

from openai.types.live import (
    CommentaryAppendedEvent,
    DelegationCreatedEvent,
    ErrorEvent,
    InfoEvent,
    InputAudioMutedEvent,
    InputAudioUnmutedEvent,
    InputTranscriptDeltaEvent,
    InstructionsAppendedEvent,
    OutputAudioDeltaEvent,
    OutputTranscriptDeltaEvent,
    SessionClosedEvent,
    SessionStartedEvent,
    SessionUpdatedEvent,
    SessionUsageUpdatedEvent,
    ThinkingAppendedEvent,
)
from pydantic import BaseModel, ValidationError

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
from by_your_command.agents.providers.gpt_live.errors import provider_error

MAX_COMMAND_CHARS: Final = 200  # robot_tool.parse_command's limit: one line, 200 characters
MAX_HEARD_CHARS: Final = 4000  # user transcript kept for one utterance (bounded memory)
_MAX_IGNORED_KINDS: Final = 64  # distinct unknown event types counted (the names are the server's)

# The server events this provider reads, by wire type: each is validated against its SDK model.
SERVER_EVENTS: Final[dict[str, type[BaseModel]]] = {
    model.model_fields["type"].annotation.__args__[0]: model  # type: ignore[union-attr]
    for model in (
        SessionStartedEvent,
        SessionUpdatedEvent,
        SessionUsageUpdatedEvent,
        SessionClosedEvent,
        OutputAudioDeltaEvent,
        OutputTranscriptDeltaEvent,
        InputTranscriptDeltaEvent,
        DelegationCreatedEvent,
        ErrorEvent,
        InfoEvent,
        InputAudioMutedEvent,
        InputAudioUnmutedEvent,
        InstructionsAppendedEvent,
        ThinkingAppendedEvent,
        CommentaryAppendedEvent,
    )
}
# Acknowledgements and notices: nothing for the runtime in them.
_QUIET_TYPES: Final = (
    SessionStartedEvent,
    SessionUpdatedEvent,
    InfoEvent,
    InputAudioMutedEvent,
    InputAudioUnmutedEvent,
    InstructionsAppendedEvent,
    ThinkingAppendedEvent,
    CommentaryAppendedEvent,
)


class UnreadableEvent(ValueError):
    """A frame that is not a server event we can read (not JSON, no type, fields of the wrong kind)."""


@dataclass(frozen=True)
class UnknownEvent:
    """An event of a type this provider does not read (Responses/Decisions delegation, sideband)."""

    type: str


def parse_server_event(raw: str | bytes) -> BaseModel | UnknownEvent:
    """One frame as its SDK model, validated (the SDK's own parser does not check fields, and reads
    an unknown type as the first model of its union)."""
    try:
        data = json.loads(raw)
    except (ValueError, RecursionError) as error:
        raise UnreadableEvent(f"not JSON: {str(error)[:80]}") from None
    kind = data.get("type") if isinstance(data, dict) else None
    if not isinstance(kind, str):
        raise UnreadableEvent("no event type")
    model = SERVER_EVENTS.get(kind)
    if model is None:
        return UnknownEvent(kind[:64])
    try:
        return model.model_validate(data)
    except ValidationError as error:
        raise UnreadableEvent(f"{kind[:64]}: {error.errors()[0]['msg'][:80]}") from None


@dataclass
class _Reply:
    response_id: str
    started_at: float
    last_output_at: float
    said: list[str] = field(default_factory=list)
    request: list[str] = field(default_factory=list)  # the user's words it answers (a delegation's task)
    cut: bool = False  # the runtime cut it (barge-in): its audio is not played

    @property
    def item_id(self) -> str:
        return self.response_id + "-audio"


class LiveTranslator:
    def __init__(
        self,
        sample_rate: int,
        reply_end_gap_s: float,
        delegation_tool: str,
        text_replies: bool = False,  # a command agent: transcripts as AssistantText, no audio
        yield_gap_s: float | None = None,  # None: reply_end_gap_s
    ) -> None:
        self.sample_rate = sample_rate
        self.reply_end_gap_s = reply_end_gap_s
        self.yield_gap_s = reply_end_gap_s if yield_gap_s is None else min(yield_gap_s, reply_end_gap_s)
        self.delegation_tool = delegation_tool
        self.text_replies = text_replies
        self.billed_seconds = 0.0  # cumulative seconds the server counts (never summed: it is a total)
        self.ignored: Counter[str] = Counter()  # event types read and dropped, by type
        self._reply: _Reply | None = None
        self._heard: list[str] = []  # user transcript not yet reported
        self._heard_at = 0.0
        self._heard_chars = 0
        self._task: list[str] = []  # what the user said since the last reply began
        self._speech_started_at: float | None = None  # the latest start of user speech we sent

    @property
    def active_response(self) -> str | None:
        return self._reply.response_id if self._reply is not None else None

    # ---- from the provider ----------------------------------------------------------------------
    def user_speech(self, now: float, starts: bool) -> None:
        """We sent user speech (`starts`: the first audio of an utterance)."""
        if starts or self._speech_started_at is None:
            self._speech_started_at = now

    def cut(self, response_id: str) -> None:
        """The runtime cut this reply (barge-in): the model decides whether it stops; its audio is
        dropped here and its end reports it cancelled."""
        reply = self._reply
        if reply is not None and (not response_id or response_id == reply.response_id):
            reply.cut = True

    def deadline(self) -> float | None:
        """When `tick` has something to end (a reply or an utterance gone quiet), if anything."""
        times = []
        if self._reply is not None:
            times.append(self._reply.last_output_at + self._quiet_gap(self._reply))
        if self._heard:
            times.append(self._heard_at + self.reply_end_gap_s)
        return min(times) if times else None

    def tick(self, now: float) -> list[ProviderEvent]:
        out: list[ProviderEvent] = []
        if self._heard and now >= self._heard_at + self.reply_end_gap_s:
            out += self._flush_heard()
        reply = self._reply
        if reply is not None and now >= reply.last_output_at + self._quiet_gap(reply):
            out += self._end_reply(reply)
        return out

    def _spoken_over(self, reply: _Reply) -> bool:
        """The user began speaking while this reply was open: its last delta's audio still sounds
        after it arrives, and a model that yields at once sends nothing after the speech began."""
        spoke = self._speech_started_at
        return spoke is not None and reply.started_at <= spoke

    def _quiet_gap(self, reply: _Reply) -> float:
        return self.yield_gap_s if self._spoken_over(reply) and not reply.cut else self.reply_end_gap_s

    def connection_lost(self, why: str) -> list[ProviderEvent]:
        """The socket is gone: report what was heard and fail the reply in flight."""
        out = self._flush_heard()
        reply, self._reply = self._reply, None
        if reply is not None:
            out.append(ResponseDone(reply.response_id, ResponseStatus.FAILED, reason=why))
        return out

    # ---- server events ---------------------------------------------------------------------------
    def translate(self, event: BaseModel | UnknownEvent, now: float) -> list[ProviderEvent]:
        if isinstance(event, OutputAudioDeltaEvent):
            return self._audio(event, now)
        if isinstance(event, OutputTranscriptDeltaEvent):
            return self._said(event.delta, now)
        if isinstance(event, InputTranscriptDeltaEvent):
            self._hear(event.delta, now)
            return []
        if isinstance(event, DelegationCreatedEvent):
            return self._delegation(event, now)
        if isinstance(event, SessionUsageUpdatedEvent):
            return self._bill(event.usage.seconds)
        if isinstance(event, SessionClosedEvent):
            return self._closed(event)
        if isinstance(event, ErrorEvent):
            return [provider_error(event.error.code, event.error.message)]
        if isinstance(event, _QUIET_TYPES):
            return []
        kind = event.type if isinstance(event, UnknownEvent) else type(event).__name__
        if kind in self.ignored or len(self.ignored) < _MAX_IGNORED_KINDS:
            self.ignored[kind] += 1
        return []

    def _start_reply(self, now: float) -> tuple[_Reply, list[ProviderEvent]]:
        reply = self._reply
        if reply is not None:
            reply.last_output_at = now
            return reply, []
        out = self._flush_heard()  # what the user said comes before the answer to it
        reply = self._reply = _Reply(f"live_{uuid.uuid4().hex[:16]}", now, now, request=self._task)
        self._task = []
        return reply, out

    def _audio(self, event: OutputAudioDeltaEvent, now: float) -> list[ProviderEvent]:
        try:
            pcm = base64.b64decode(event.delta, validate=True)
        except (binascii.Error, ValueError):
            return [ProviderError("invalid_server_event", "audio delta that is not base64: dropped")]
        pcm = pcm[: len(pcm) - len(pcm) % 2]  # whole int16 samples only
        if not pcm:
            return []
        reply, out = self._start_reply(now)
        if not (reply.cut or self.text_replies):
            out.append(AssistantAudio(reply.response_id, reply.item_id, pcm, self.sample_rate))
        return out

    def _said(self, delta: str, now: float) -> list[ProviderEvent]:
        if not delta:
            return []
        reply, out = self._start_reply(now)
        if sum(map(len, reply.said)) < MAX_HEARD_CHARS:
            reply.said.append(delta)
            if not self.text_replies:
                out.append(AssistantTranscript(reply.response_id, reply.item_id, delta, final=False))
            else:
                out.append(AssistantText(reply.response_id, reply.item_id, delta, final=False))
        return out

    def _hear(self, delta: str, now: float) -> None:
        if delta and self._heard_chars < MAX_HEARD_CHARS:
            self._heard.append(delta)
            self._task.append(delta)
            self._heard_chars += len(delta)
        self._heard_at = now

    def _flush_heard(self) -> list[ProviderEvent]:
        if not self._heard:
            return []
        text = "".join(self._heard).strip()
        self._heard, self._heard_chars = [], 0
        return [UserTranscript(text, f"live_heard_{uuid.uuid4().hex[:12]}")]

    def _delegation(self, event: DelegationCreatedEvent, now: float) -> list[ProviderEvent]:
        if event.delegation.target != "client":
            self.ignored["delegation:" + event.delegation.target] += 1
            return []
        reply, out = self._start_reply(now)
        # The request this reply answers, and anything the user added since.
        command = " ".join("".join(reply.request + self._task).split())[:MAX_COMMAND_CHARS]
        reply.request, self._task = [], []
        arguments = json.dumps({"command": command})
        out.append(ToolCall(reply.response_id, event.delegation.id, self.delegation_tool, arguments))
        return out

    def _end_reply(self, reply: _Reply) -> list[ProviderEvent]:
        self._reply = None
        out: list[ProviderEvent] = []
        # It was talking when the user began, and stopped: the model yielded (it decides barge-in).
        # Said first, so the runtime cuts the player (and marks the words cut) before they are kept.
        yielded = not reply.cut and self._spoken_over(reply)
        if yielded:
            out.append(Interrupted(reply.response_id))
        text = "".join(reply.said).strip()
        if text:
            final = AssistantText if self.text_replies else AssistantTranscript
            out.append(final(reply.response_id, reply.item_id, text, final=True))
        if reply.cut:
            out.append(ResponseDone(reply.response_id, ResponseStatus.CANCELLED, reason="cut by the user"))
        elif yielded:
            why = "the model yielded to the user"
            out.append(ResponseDone(reply.response_id, ResponseStatus.CANCELLED, reason=why))
        else:
            out.append(ResponseDone(reply.response_id, ResponseStatus.COMPLETED))
        return out

    def _bill(self, seconds: float) -> list[ProviderEvent]:
        """A total: keep the largest (a NaN or a smaller total is no news); report the increase."""
        if not (math.isfinite(seconds) and seconds > self.billed_seconds):
            return []
        added, self.billed_seconds = seconds - self.billed_seconds, float(seconds)
        return [UsageReport(Usage(session_s=added))]

    def _closed(self, event: SessionClosedEvent) -> list[ProviderEvent]:
        out = self._bill(event.usage.seconds)
        if event.reason == "expired":
            out.append(SessionEnding("the GPT-Live session expired", 0.0))
        elif event.reason == "content":
            why = "GPT-Live closed the session (content filter)"
            out.append(ProviderError("session_closed_content", why))
        return out
