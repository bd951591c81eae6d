"""`agent_metrics` records (agents/metrics.py) read back from untrusted JSON text.

Anything on the topic may come from any bridge client, so every field is checked: a record that is
not what an agent publishes raises `BadRecord` (counted by the summary, never a crash).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

MAX_RECORD_CHARS = 65_536  # an agent's record is a few hundred characters
MAX_NAME_CHARS = 64
MAX_REASON_CHARS = 200
MAX_STREAM_ID_CHARS = 200  # a reply's audio stream id (matched whole against playback_status, never cut)
MAX_REQUEST_ID_CHARS = 200  # a robot tool call's id (a key: matched whole, never cut)
MAX_ARGUMENTS_CHARS = 200  # the agent cuts a call's arguments to this
MAX_DEPTH = 8  # nested objects and lists (an agent's record has 2)
MAX_COUNT = 10**12  # tokens, turns, serials: far above anything real, far below float trouble


class BadRecord(ValueError):
    """Not an agent_metrics record; the message says why (without echoing the whole text)."""


@dataclass(frozen=True)
class Tokens:
    input_text: int = 0
    input_audio: int = 0
    input_image: int = 0
    cached_input: int = 0
    output_text: int = 0
    output_audio: int = 0
    session_s: float = 0.0  # a per-second provider's own count of the billed session time

    @property
    def input(self) -> int:
        return self.input_text + self.input_audio + self.input_image

    @property
    def output(self) -> int:
        return self.output_text + self.output_audio

    def __add__(self, other: Tokens) -> Tokens:
        return Tokens(
            self.input_text + other.input_text,
            self.input_audio + other.input_audio,
            self.input_image + other.input_image,
            self.cached_input + other.cached_input,
            self.output_text + other.output_text,
            self.output_audio + other.output_audio,
            self.session_s + other.session_s,
        )


@dataclass(frozen=True)
class TurnRecord:
    agent_id: str
    provider: str
    session: int
    turn: int
    outcome: str
    first_audio_ms: float | None
    reply_ms: float  # end of user speech → reply generated (not played: playback_status says that)
    tokens: Tokens
    reason: str = ""  # why it failed or was not delivered (optional: older agents send none)
    stream_id: str = ""  # the reply's response_voice stream, when the agent names it (optional)


@dataclass(frozen=True)
class SessionRecord:
    agent_id: str
    provider: str
    session: int
    billed_s: float
    turns: int
    close_reason: str
    tokens: Tokens


@dataclass(frozen=True)
class SessionOpenRecord:
    agent_id: str
    provider: str
    session: int


@dataclass(frozen=True)
class ToolCallRecord:
    """A robot tool call started, made progress or ended (agents/metrics.ToolCallMetrics)."""

    agent_id: str
    request_id: str
    tool: str
    kind: str  # one of TOOL_KINDS
    arguments: str  # the model's arguments as JSON text (cut): shown, never parsed
    state: str  # RUNNING or one of ENDED_STATES
    progress: str  # the latest feedback summary
    elapsed_s: float  # since the call was sent, when the agent published the record
    error: str


TOOL_KINDS = ("action", "service", "topic", "command")
RUNNING = "running"
ENDED_STATES = (
    "succeeded",
    "failed",
    "rejected",
    "cancelled",
    "timeout",
    "refused",
    "unavailable",
    "published",
)

Record = TurnRecord | SessionRecord | SessionOpenRecord | ToolCallRecord

# JSON names of the usage fields (agents/events.Usage) → Tokens fields.
_USAGE_FIELDS = {
    "input_text_tokens": "input_text",
    "input_audio_tokens": "input_audio",
    "input_image_tokens": "input_image",
    "cached_input_tokens": "cached_input",
    "output_text_tokens": "output_text",
    "output_audio_tokens": "output_audio",
}


def parse_record(text: str) -> Record:
    if len(text) > MAX_RECORD_CHARS:
        raise BadRecord(f"record of {len(text)} characters (at most {MAX_RECORD_CHARS})")
    try:
        data = json.loads(text, parse_constant=_no_constant)
    except (ValueError, RecursionError) as error:
        raise BadRecord(f"not JSON: {str(error)[:80]}") from None
    if not isinstance(data, dict):
        raise BadRecord("not a JSON object")
    if _too_deep(data, 1):
        raise BadRecord(f"nested deeper than {MAX_DEPTH} levels")
    kind = data.get("record")
    agent_id = _name(data, "agent_id", required=True)
    if kind == "tool_call":  # carries no provider nor session
        return _tool_call(data, agent_id)
    provider = _name(data, "provider", required=False)
    session = _count(data, "session")
    if kind == "session_open":
        return SessionOpenRecord(agent_id, provider, session)
    tokens = _tokens(data.get("usage", {}))
    if kind == "turn":
        return TurnRecord(
            agent_id,
            provider,
            session,
            _count(data, "turn"),
            _text(data, "outcome", MAX_NAME_CHARS),
            _millis(data, "first_audio_ms", optional=True),
            _millis(data, "reply_ms", optional=False) or 0.0,
            tokens,
            _optional_text(data, "reason", MAX_REASON_CHARS),
            _stream_id(data),
        )
    if kind == "session":
        return SessionRecord(
            agent_id,
            provider,
            session,
            _number(data, "billed_s"),
            _count(data, "turns"),
            _text(data, "close_reason", MAX_REASON_CHARS),
            tokens,
        )
    raise BadRecord(
        f"record must be 'turn', 'session', 'session_open' or 'tool_call', got {str(kind)[:20]!r}"
    )


def _tool_call(data: dict[str, Any], agent_id: str) -> ToolCallRecord:
    return ToolCallRecord(
        agent_id,
        _request_id(data),
        _name(data, "tool", required=True),
        _one_of(data, "kind", TOOL_KINDS),
        _text(data, "arguments", MAX_ARGUMENTS_CHARS),
        _one_of(data, "state", (RUNNING, *ENDED_STATES)),
        _optional_text(data, "progress", MAX_REASON_CHARS),
        _number(data, "elapsed_s"),
        _optional_text(data, "error", MAX_REASON_CHARS),
    )


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number")


def _too_deep(value: Any, depth: int) -> bool:
    """A fixed limit the page applies too (json's own RecursionError depends on the stack)."""
    if not isinstance(value, (dict, list)):
        return False
    if depth > MAX_DEPTH:
        return True
    children = value.values() if isinstance(value, dict) else value
    return any(_too_deep(child, depth + 1) for child in children)


def _name(data: dict[str, Any], key: str, required: bool) -> str:
    value = data.get(key, "")
    if not isinstance(value, str) or (required and not value.strip()):
        raise BadRecord(f"{key}: expected a non-empty string" if required else f"{key}: expected a string")
    return " ".join(value.split())[:MAX_NAME_CHARS]


def _text(data: dict[str, Any], key: str, limit: int) -> str:
    value = data.get(key)
    if not isinstance(value, str):
        raise BadRecord(f"{key}: expected a string")
    return " ".join(value.split())[:limit]


def _optional_text(data: dict[str, Any], key: str, limit: int) -> str:
    return _text(data, key, limit) if data.get(key) is not None else ""


def _stream_id(data: dict[str, Any]) -> str:
    value = data.get("stream_id")
    if value is None:
        return ""
    if not isinstance(value, str) or len(value) > MAX_STREAM_ID_CHARS:
        raise BadRecord(f"stream_id: expected a string of at most {MAX_STREAM_ID_CHARS} characters")
    return value


def _request_id(data: dict[str, Any]) -> str:
    value = data.get("request_id")
    if not isinstance(value, str) or not 0 < len(value) <= MAX_REQUEST_ID_CHARS:
        raise BadRecord(f"request_id: expected a string of 1..{MAX_REQUEST_ID_CHARS} characters")
    return value


def _one_of(data: dict[str, Any], key: str, allowed: tuple[str, ...]) -> str:
    value = data.get(key)
    if not isinstance(value, str) or value not in allowed:
        raise BadRecord(f"{key}: expected one of {', '.join(allowed)}")
    return value


def _count(data: dict[str, Any], key: str) -> int:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_COUNT:
        raise BadRecord(f"{key}: expected an integer 0..{MAX_COUNT}")
    return value


def _number(data: dict[str, Any], key: str) -> float:
    value = data.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise BadRecord(f"{key}: expected a number")
    # The range before float() (which raises on a 400-digit integer); NaN fails any comparison.
    if not 0 <= value <= MAX_COUNT:
        raise BadRecord(f"{key}: expected a number 0..{MAX_COUNT}")
    return float(value)


def _millis(data: dict[str, Any], key: str, optional: bool) -> float | None:
    if optional and data.get(key) is None:
        return None
    return _number(data, key)


def _tokens(usage: Any) -> Tokens:
    if not isinstance(usage, dict):
        raise BadRecord("usage: expected an object")
    values: dict[str, Any] = {}
    try:
        for key, name in _USAGE_FIELDS.items():
            values[name] = _count(usage, key) if key in usage else 0
        values["session_s"] = _number(usage, "session_s") if "session_s" in usage else 0.0
    except BadRecord as error:
        raise BadRecord(f"usage.{error}") from None
    return Tokens(**values)
