"""The events every provider emits, whatever its vendor: the runtime only ever sees these.

Audio is mono signed 16-bit little-endian PCM with its rate alongside; ids are the provider's
own (OpenAI item/response ids, or ids the provider invents) so a cut names what it cuts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum


class ResponseStatus(str, Enum):
    COMPLETED = "completed"
    CANCELLED = "cancelled"
    FAILED = "failed"
    INCOMPLETE = "incomplete"  # stopped early by a limit (max tokens, content filter)


@dataclass(frozen=True)
class Usage:
    """Tokens billed for one response (or one input transcription). Image tokens are counted
    apart because they are priced apart and are easy to forget in cost figures. A per-second
    provider (GPT-Live) bills open session time instead: `session_s`."""

    input_text_tokens: int = 0
    input_audio_tokens: int = 0
    input_image_tokens: int = 0
    cached_input_tokens: int = 0
    output_text_tokens: int = 0
    output_audio_tokens: int = 0
    # Seconds of open session the vendor bills, as the server counted them (per-second providers
    # only; each report carries the increase since the previous one, so sums are totals).
    session_s: float = 0.0

    @property
    def input_tokens(self) -> int:
        return self.input_text_tokens + self.input_audio_tokens + self.input_image_tokens

    @property
    def output_tokens(self) -> int:
        return self.output_text_tokens + self.output_audio_tokens

    def __add__(self, other: Usage) -> Usage:
        return Usage(
            self.input_text_tokens + other.input_text_tokens,
            self.input_audio_tokens + other.input_audio_tokens,
            self.input_image_tokens + other.input_image_tokens,
            self.cached_input_tokens + other.cached_input_tokens,
            self.output_text_tokens + other.output_text_tokens,
            self.output_audio_tokens + other.output_audio_tokens,
            self.session_s + other.session_s,
        )


@dataclass(frozen=True)
class UserTranscript:
    """What the provider heard the user say (may arrive after the reply started)."""

    text: str
    item_id: str = ""
    usage: Usage = field(default_factory=Usage)


@dataclass(frozen=True)
class AssistantAudio:
    response_id: str
    item_id: str
    pcm: bytes
    sample_rate: int


@dataclass(frozen=True)
class AssistantTranscript:
    """Transcript of the assistant's spoken reply: `delta` pieces, then one `final` full text."""

    response_id: str
    item_id: str
    text: str
    final: bool


@dataclass(frozen=True)
class AssistantText:
    """A text-only reply (command agents): `delta` pieces, then one `final` full text."""

    response_id: str
    item_id: str
    text: str
    final: bool


@dataclass(frozen=True)
class ToolCall:
    response_id: str
    call_id: str
    name: str
    arguments: str  # JSON text as the model wrote it; validated by the tool, not trusted


@dataclass(frozen=True)
class ToolCallCancelled:
    """The provider withdrew these calls (Gemini's toolCallCancellation, sent when the user cuts in):
    no result may be sent for them, and a command not yet routed to the robot is not routed."""

    call_ids: tuple[str, ...]


@dataclass(frozen=True)
class ResponseDone:
    response_id: str
    status: ResponseStatus
    usage: Usage = field(default_factory=Usage)
    reason: str = ""


@dataclass(frozen=True)
class Interrupted:
    """The provider itself stopped a reply (e.g. Gemini's `interrupted`)."""

    response_id: str


@dataclass(frozen=True)
class UsageReport:
    """Usage not tied to one response: a per-second provider's billed session time (GPT-Live's
    `session.usage.updated`), as the increase since its previous report."""

    usage: Usage


@dataclass(frozen=True)
class SessionEnding:
    """The provider will close the session soon (limit reached, goAway): rotate at a turn boundary."""

    reason: str
    seconds_left: float


@dataclass(frozen=True)
class ProviderError:
    """An error reported by the provider. `fatal` ones (bad key, unknown model) stop the agent with
    one clear message; others are logged and counted; `retry_after_s` asks for a back-off."""

    code: str
    message: str
    fatal: bool = False
    retry_after_s: float | None = None
    # The input of the turn in flight was not accepted (e.g. audio too short to commit): no reply
    # will come, so that turn fails now instead of holding every later turn until the reply timeout.
    refuses_turn: bool = False


ProviderEvent = (
    UserTranscript
    | AssistantAudio
    | AssistantTranscript
    | AssistantText
    | ToolCall
    | ToolCallCancelled
    | ResponseDone
    | Interrupted
    | UsageReport
    | SessionEnding
    | ProviderError
)
