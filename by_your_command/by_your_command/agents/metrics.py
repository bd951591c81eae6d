"""Records the agent publishes (per turn, per session) and the counters behind "nothing lost silently"."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any

from by_your_command.agents.events import Usage


@dataclass(frozen=True)
class TurnMetrics:
    agent_id: str
    conversation_id: str
    session: int  # serial of the provider session that served the turn
    turn: int
    turn_kind: str  # "voice" | "text"
    # "completed" | "cancelled" | "failed" | "interrupted" | "incomplete" | "undelivered"
    outcome: str
    first_audio_ms: float | None  # end of user speech (end marker / text) → first reply audio published
    reply_ms: float  # end of user speech → reply finished
    usage: Usage = field(default_factory=Usage)
    provider: str = ""  # Provider.name (monitors price the tokens per provider)
    reason: str = ""  # why it failed or was not delivered (a report: never said as the robot's words)
    stream_id: str = ""  # the reply's last stream (its playback_status says when it stopped playing)

    def as_dict(self) -> dict[str, Any]:
        return {"record": "turn", **_flatten(self)}


@dataclass(frozen=True)
class SessionMetrics:
    agent_id: str
    conversation_id: str
    session: int
    billed_s: float  # connect started → closed: what the vendor bills for a realtime session
    turns: int
    close_reason: str
    usage: Usage = field(default_factory=Usage)
    provider: str = ""  # Provider.name (monitors price the tokens per provider)

    def as_dict(self) -> dict[str, Any]:
        return {"record": "session", **_flatten(self)}


@dataclass(frozen=True)
class SessionOpenedMetrics:
    """A provider session is open (billing runs from here): monitors show it before its first turn."""

    agent_id: str
    conversation_id: str
    session: int
    provider: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {"record": "session_open", **asdict(self)}


@dataclass(frozen=True)
class ToolCallMetrics:
    """A robot tool call (docs/tools.md) started, made progress or ended: monitors show the
    robot's active goals, their latest feedback and how each ended."""

    agent_id: str
    request_id: str  # the id the bridge and the robot saw
    tool: str
    kind: str  # action | service | topic | command
    arguments: str  # the model's arguments (JSON, cut to 200 characters)
    # running | succeeded | failed | rejected | cancelled | timeout | refused | unavailable | published
    state: str
    progress: str = ""  # the latest feedback summary told to the model
    elapsed_s: float = 0.0  # since the call was sent
    error: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {"record": "tool_call", **asdict(self)}


MetricsRecord = TurnMetrics | SessionMetrics | SessionOpenedMetrics | ToolCallMetrics


def _flatten(record: TurnMetrics | SessionMetrics) -> dict[str, Any]:
    data = asdict(record)
    usage: Usage = record.usage
    data["usage"] = {
        **asdict(usage),
        "input_tokens": usage.input_tokens,
        "output_tokens": usage.output_tokens,
    }
    return data


@dataclass
class Counters:
    """Cumulative counts of everything that went wrong or was deliberately not done (logged as they
    change, included in `snapshot()`)."""

    turns: int = 0
    turns_failed: int = 0
    utterances_undeliverable: int = 0
    chunks_missing: int = 0  # gaps in chunk_sequence
    end_markers_missing: int = 0  # utterances closed by the idle deadline
    stray_chunks: int = 0  # chunks of an utterance already closed
    inputs_lost: int = 0  # messages the bridge reported lost (unknown counts count 1)
    inputs_invalid: int = 0
    ignored_not_awake: int = 0  # utterances / texts not sent while asleep or muted
    barge_ins: int = 0
    false_barge_ins: int = 0
    safety_stops: int = 0  # the robot heard "stop" itself (safety_stop): reply cut
    empty_transcripts: int = 0
    publish_failures: int = 0
    provider_errors: int = 0
    sessions_opened: int = 0
    connect_failures: int = 0
    sessions_failed: int = 0  # sessions that died or were recycled after a failure
    tool_calls: int = 0
    tool_timeouts: int = 0
    tool_calls_cancelled: int = (
        0  # withdrawn by the provider: no result sent (commands_withheld: never routed)
    )
    commands_withheld: int = 0
    detections_published: int = 0  # replies whose boxes went out on `detections`
    detections_dropped: int = 0  # boxes found but not published (agent without `detections: true`)
    detections_refused: int = 0  # entries that were no usable box (bad JSON, NaN, empty box, over the limits)
    internal_errors: int = 0

    def snapshot(self) -> dict[str, int]:
        return {item.name: getattr(self, item.name) for item in fields(self)}
