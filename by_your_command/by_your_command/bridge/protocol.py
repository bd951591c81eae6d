"""Typed rosbridge v2 protocol messages: parse and validate every inbound frame, encode outbound ones.

Only the subset the bridge serves is modelled (topics; no services, actions or fragments).
Type names are accepted as `pkg/Type` (ROS 1 style, what roslibpy sends) or `pkg/msg/Type`
and normalised to `pkg/msg/Type`.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from typing import Any, Literal

StatusLevel = Literal["error", "warning", "info"]

_TYPE_RE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(?:msg/)?([A-Za-z][A-Za-z0-9_]*)$")
_TOPIC_RE = re.compile(r"^/?[A-Za-z~][A-Za-z0-9_/~]*$")


class ProtocolError(ValueError):
    """An inbound frame that is not a valid request; `request_id` echoes the client's id if known."""

    def __init__(self, message: str, request_id: str | None = None, op: str | None = None) -> None:
        super().__init__(message)
        self.request_id = request_id
        self.op = op


def normalize_type(type_name: str) -> str:
    """`std_msgs/String` or `std_msgs/msg/String` → `std_msgs/msg/String`; anything else is an error."""
    match = _TYPE_RE.match(type_name)
    if match is None:
        raise ValueError(f"invalid message type {type_name!r} (expected pkg/Type or pkg/msg/Type)")
    return f"{match.group(1)}/msg/{match.group(2)}"


@dataclass(frozen=True)
class Advertise:
    topic: str
    type: str
    id: str | None = None


@dataclass(frozen=True)
class Unadvertise:
    topic: str
    id: str | None = None


@dataclass(frozen=True)
class Publish:
    topic: str
    msg: dict[str, Any]
    id: str | None = None


@dataclass(frozen=True)
class Subscribe:
    topic: str
    type: str | None = None
    throttle_rate_ms: int = 0  # minimum interval between two messages to this client
    queue_length: int = 0  # 0: the bridge's default per-subscription bound
    id: str | None = None


@dataclass(frozen=True)
class Unsubscribe:
    topic: str
    id: str | None = None


@dataclass(frozen=True)
class Status:
    level: StatusLevel
    msg: str
    id: str | None = None
    # Our addition: machine-readable reason code and topic, ignored by stock clients.
    code: str = ""
    topic: str = ""
    counts: dict[str, int] = field(default_factory=dict)


Request = Advertise | Unadvertise | Publish | Subscribe | Unsubscribe


def _string(data: dict[str, Any], key: str, op: str, request_id: str | None, required: bool = True) -> str:
    value = data.get(key)
    if value is None and not required:
        return ""
    if not isinstance(value, str) or not value:
        raise ProtocolError(f"'{op}' needs a non-empty string '{key}'", request_id, op)
    return value


def _topic(data: dict[str, Any], op: str, request_id: str | None) -> str:
    topic = _string(data, "topic", op, request_id)
    if not _TOPIC_RE.match(topic) or "//" in topic or topic.endswith("/"):
        raise ProtocolError(f"invalid topic name {topic!r}", request_id, op)
    return topic


def _type(data: dict[str, Any], op: str, request_id: str | None, required: bool) -> str | None:
    raw = _string(data, "type", op, request_id, required=required)
    if not raw:
        return None
    try:
        return normalize_type(raw)
    except ValueError as error:
        raise ProtocolError(str(error), request_id, op) from None


def _non_negative_int(data: dict[str, Any], key: str, op: str, request_id: str | None) -> int:
    value = data.get(key, 0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
        raise ProtocolError(f"'{op}' field '{key}' must be a non-negative number", request_id, op)
    return int(value)


def parse_request(text: str | bytes) -> Request:
    """Parse one inbound frame; raise ProtocolError with a message fit to send back to the client."""
    try:
        data = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ProtocolError(f"malformed JSON: {error}") from None
    if not isinstance(data, dict):
        raise ProtocolError("a request must be a JSON object")
    raw_id = data.get("id")
    request_id = None if raw_id is None else str(raw_id)
    op = data.get("op")
    if not isinstance(op, str):
        raise ProtocolError("missing 'op'", request_id)
    if op == "advertise":
        return Advertise(_topic(data, op, request_id), _type(data, op, request_id, True) or "", request_id)
    if op == "unadvertise":
        return Unadvertise(_topic(data, op, request_id), request_id)
    if op == "publish":
        msg = data.get("msg", {})
        if not isinstance(msg, dict):
            raise ProtocolError("'publish' field 'msg' must be a JSON object", request_id, op)
        return Publish(_topic(data, op, request_id), msg, request_id)
    if op == "subscribe":
        compression = data.get("compression", "none")
        if compression not in (None, "none"):
            raise ProtocolError(f"compression {compression!r} is not supported (only 'none')", request_id, op)
        return Subscribe(
            _topic(data, op, request_id),
            _type(data, op, request_id, False),
            _non_negative_int(data, "throttle_rate", op, request_id),
            _non_negative_int(data, "queue_length", op, request_id),
            request_id,
        )
    if op == "unsubscribe":
        return Unsubscribe(_topic(data, op, request_id), request_id)
    raise ProtocolError(f"unsupported op {op!r}", request_id, op)


def encode_status(status: Status) -> str:
    frame: dict[str, Any] = {"op": "status", "level": status.level, "msg": status.msg}
    if status.id is not None:
        frame["id"] = status.id
    if status.code:
        frame["code"] = status.code
    if status.topic:
        frame["topic"] = status.topic
    if status.counts:
        frame["counts"] = status.counts
    return json.dumps(frame, separators=(",", ":"))


def encode_publish(topic: str, msg_json: str) -> str:
    """A `publish` frame around an already-encoded message (encoded once, shared by every client)."""
    return f'{{"op":"publish","topic":{json.dumps(topic)},"msg":{msg_json}}}'


def encode_request(request: Request) -> str:
    """Client side: the JSON frame for a request."""
    frame: dict[str, Any]
    if isinstance(request, Advertise):
        frame = {"op": "advertise", "topic": request.topic, "type": request.type}
    elif isinstance(request, Unadvertise):
        frame = {"op": "unadvertise", "topic": request.topic}
    elif isinstance(request, Publish):
        frame = {"op": "publish", "topic": request.topic, "msg": request.msg}
    elif isinstance(request, Subscribe):
        frame = {"op": "subscribe", "topic": request.topic}
        if request.type:
            frame["type"] = request.type
        if request.throttle_rate_ms:
            frame["throttle_rate"] = request.throttle_rate_ms
        if request.queue_length:
            frame["queue_length"] = request.queue_length
    else:
        frame = {"op": "unsubscribe", "topic": request.topic}
    if request.id is not None:
        frame["id"] = request.id
    return json.dumps(frame, separators=(",", ":"))


@dataclass(frozen=True)
class Incoming:
    """What a client receives: a message on a topic, or a status."""

    topic: str
    msg: dict[str, Any]


def parse_server_frame(text: str | bytes) -> Incoming | Status:
    """Client side: parse a bridge frame; raise ProtocolError for anything unexpected."""
    try:
        data = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ProtocolError(f"malformed JSON from server: {error}") from None
    if not isinstance(data, dict):
        raise ProtocolError("server frame is not a JSON object")
    op = data.get("op")
    if op == "publish" and isinstance(data.get("topic"), str) and isinstance(data.get("msg"), dict):
        return Incoming(data["topic"], data["msg"])
    if op == "status":
        level = data.get("level", "info")
        counts = data.get("counts") or {}
        return Status(
            level if level in ("error", "warning", "info") else "info",
            str(data.get("msg", "")),
            None if data.get("id") is None else str(data["id"]),
            str(data.get("code", "")),
            str(data.get("topic", "")),
            {str(k): int(v) for k, v in counts.items()} if isinstance(counts, dict) else {},
        )
    raise ProtocolError(f"unexpected server frame op {op!r}")
