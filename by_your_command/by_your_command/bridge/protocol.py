"""Typed rosbridge v2 protocol messages: parse and validate every inbound frame, encode outbound ones.

Only the subset the bridge serves is modelled: topics, service calls and action goals as a client
(no fragments, no advertised services or actions). Type names are accepted as `pkg/Type` (ROS 1
style, what roslibpy sends) or `pkg/msg/Type` and normalised to `pkg/msg/Type`; service and action
types likewise to `pkg/srv/Type` and `pkg/action/Type`.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from typing import Any, Literal

StatusLevel = Literal["error", "warning", "info"]
# A request id comes back exactly as the client sent it: a JSON string or integer.
RequestId = str | int

MAX_JSON_DEPTH = 32  # rosbridge requests and our message types nest far less than this
MAX_NUMBER_CHARS = 64  # a float literal longer than this is not a measurement, it is an attack
MAX_ID_CHARS = 128
MAX_ID_INT = 2**63 - 1
PREVIEW_CHARS = 64  # client strings quoted in replies and logs are cut to this

# Used with fullmatch: `$` would also match before a final newline ("prompt_text\n").
_TYPE_RE = re.compile(r"([A-Za-z][A-Za-z0-9_]*)/(?:msg/)?([A-Za-z][A-Za-z0-9_]*)")
_TOPIC_RE = re.compile(r"/?[A-Za-z~][A-Za-z0-9_/~]*")
_INTERFACE_RE = {
    kind: re.compile(rf"([A-Za-z][A-Za-z0-9_]*)/(?:{kind}/)?([A-Za-z][A-Za-z0-9_]*)")
    for kind in ("srv", "action")
}
MAX_TOPIC_CHARS = 256  # topic, service and action names, and type names
MAX_CALL_TIMEOUT_S = 3600.0  # a call_service `timeout` beyond an hour is a mistake, not a wish


class ProtocolError(ValueError):
    """An inbound frame that is not a valid request; `request_id` echoes the client's id if known.

    `target` is the service or action name of a refused call or goal when it was valid: the
    refusal then also answers the call itself (a failing `service_response`/`action_result`).
    """

    def __init__(
        self, message: str, request_id: RequestId | None = None, op: str | None = None, target: str = ""
    ) -> None:
        super().__init__(message)
        self.request_id = request_id
        self.op = op
        self.target = target


def preview(value: object, limit: int = PREVIEW_CHARS) -> str:
    """A client-supplied value quoted for a reply or a log line: repr, cut to `limit` characters.

    Never echo what a client sent in full: a 1 MB topic name would be copied into every refusal.
    """
    if not isinstance(value, str):
        return f"<{type(value).__name__}>"
    text = value
    quoted = repr(text[: limit + 1])
    return quoted if len(text) <= limit else f"{quoted[:-1]}…{quoted[-1]} ({len(text)} chars)"


def utf8_size(frame: str | bytes) -> int:
    """Size in bytes as on the wire (a "€" is 3 bytes): every limit and counter is in these."""
    if isinstance(frame, bytes):
        return len(frame)
    return len(frame) if frame.isascii() else len(frame.encode("utf-8", "surrogatepass"))


def _refuse_constant(name: str) -> Any:
    raise ProtocolError(f"{name} is not a JSON number (non-finite numbers are refused)")


def _finite_float(literal: str) -> float:
    if len(literal) > MAX_NUMBER_CHARS:
        raise ProtocolError(f"number literal of {len(literal)} characters is too long")
    value = float(literal)
    if not math.isfinite(value):
        raise ProtocolError(f"number {preview(literal, 24)} is out of range")
    return value


def _too_deep(value: Any, limit: int) -> bool:
    """Iterative depth check (no recursion on attacker-controlled structure)."""
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if depth > limit:
            return True
        children = item.values() if isinstance(item, dict) else item
        stack.extend((child, depth + 1) for child in children if isinstance(child, (dict, list)))
    return False


def load_json(text: str | bytes, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """`json.loads` for untrusted input: every failure is a ProtocolError, never another exception.

    Refuses NaN/Infinity, float literals that overflow (1e400) or are absurdly long, integers over
    Python's digit limit (its int parser raises ValueError) and nesting deeper than `max_depth`.
    """
    try:
        data = json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float)
    except ProtocolError:
        raise
    except RecursionError:
        raise ProtocolError(f"JSON nested deeper than {max_depth} levels") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ProtocolError(f"malformed JSON: {error}") from None
    except ValueError:  # int('9' * 5000): "Exceeds the limit (4300 digits) for integer string conversion"
        raise ProtocolError("malformed JSON: a number is too large") from None
    # Counting openers is C-speed; only frames with many of them (usually inside strings) need the walk.
    openers = (
        text.count(b"[") + text.count(b"{") if isinstance(text, bytes) else text.count("[") + text.count("{")
    )
    if openers > max_depth and isinstance(data, (dict, list)) and _too_deep(data, max_depth):
        raise ProtocolError(f"JSON nested deeper than {max_depth} levels")
    return data


def normalize_type(type_name: str) -> str:
    """`std_msgs/String` or `std_msgs/msg/String` → `std_msgs/msg/String`; anything else is an error."""
    match = _TYPE_RE.fullmatch(type_name)
    if match is None:
        raise ValueError(f"invalid message type {type_name!r} (expected pkg/Type or pkg/msg/Type)")
    return f"{match.group(1)}/msg/{match.group(2)}"


InterfaceKind = Literal["srv", "action"]


def normalize_interface(type_name: str, kind: InterfaceKind) -> str:
    """`std_srvs/Trigger` or `std_srvs/srv/Trigger` → `std_srvs/srv/Trigger` (kind "srv"), likewise
    `pkg/action/T` for kind "action"; anything else (a message type included) is a ValueError."""
    match = _INTERFACE_RE[kind].fullmatch(type_name) if len(type_name) <= MAX_TOPIC_CHARS else None
    if match is None:
        raise ValueError(f"invalid {kind} type {type_name!r} (expected pkg/Type or pkg/{kind}/Type)")
    return f"{match.group(1)}/{kind}/{match.group(2)}"


@dataclass(frozen=True)
class Advertise:
    topic: str
    type: str
    id: RequestId | None = None


@dataclass(frozen=True)
class Unadvertise:
    topic: str
    id: RequestId | None = None


@dataclass(frozen=True)
class Publish:
    topic: str
    msg: dict[str, Any]
    id: RequestId | None = None


@dataclass(frozen=True)
class Subscribe:
    topic: str
    type: str | None = None
    throttle_rate_ms: int = 0  # minimum interval between two messages to this client
    queue_length: int = 0  # 0: the bridge's default per-subscription bound
    id: RequestId | None = None


@dataclass(frozen=True)
class Unsubscribe:
    topic: str
    id: RequestId | None = None


@dataclass(frozen=True)
class Status:
    level: StatusLevel
    msg: str
    id: RequestId | None = None
    # Our addition: machine-readable reason code and topic, ignored by stock clients.
    code: str = ""
    topic: str = ""
    counts: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class CallService:
    """Call a ROS service; answered by one `service_response` with the same id."""

    service: str
    args: dict[str, Any]
    id: RequestId  # required: the response is matched by it
    type: str | None = None  # pkg/srv/Type when the client names it (checked against the allow-list)
    timeout_s: float | None = None  # the client's bound; the allow-list's may be shorter


@dataclass(frozen=True)
class SendActionGoal:
    """Send a goal to a ROS action; answered by `action_feedback`s (if asked) and one `action_result`."""

    action: str
    action_type: str  # pkg/action/Type
    args: dict[str, Any]
    id: RequestId  # required: feedback, result and cancel_action_goal refer to the goal by it
    feedback: bool = False  # rosbridge's default: no feedback unless asked


@dataclass(frozen=True)
class CancelActionGoal:
    """Cancel the goal that the client sent with `send_action_goal` id `id`."""

    action: str
    id: RequestId


Request = (
    Advertise
    | Unadvertise
    | Publish
    | Subscribe
    | Unsubscribe
    | CallService
    | SendActionGoal
    | CancelActionGoal
)
CALL_OPS = ("call_service", "send_action_goal", "cancel_action_goal")


def _string(
    data: dict[str, Any], key: str, op: str, request_id: RequestId | None, required: bool = True
) -> str:
    value = data.get(key)
    if value is None and not required:
        return ""
    if not isinstance(value, str) or not value:
        raise ProtocolError(f"'{op}' needs a non-empty string '{key}'", request_id, op)
    return value


def _topic(data: dict[str, Any], op: str, request_id: RequestId | None, key: str = "topic") -> str:
    """A topic, service or action name (`key`): the same rules for all three."""
    name = _string(data, key, op, request_id)
    if len(name) > MAX_TOPIC_CHARS or not _TOPIC_RE.fullmatch(name) or "//" in name or name.endswith("/"):
        raise ProtocolError(f"invalid {key} name {preview(name)}", request_id, op)
    return name


def _type(data: dict[str, Any], op: str, request_id: RequestId | None, required: bool) -> str | None:
    raw = _string(data, "type", op, request_id, required=required)
    if not raw:
        return None
    if len(raw) > MAX_TOPIC_CHARS:
        raise ProtocolError(f"invalid message type {preview(raw)}", request_id, op)
    try:
        return normalize_type(raw)
    except ValueError:
        raise ProtocolError(
            f"invalid message type {preview(raw)} (expected pkg/Type or pkg/msg/Type)", request_id, op
        ) from None


MAX_OPTION_VALUE = 2**31 - 1  # throttle_rate (ms) and queue_length: beyond this they mean nothing


def _non_negative_int(data: dict[str, Any], key: str, op: str, request_id: RequestId | None) -> int:
    value = data.get(key, 0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= MAX_OPTION_VALUE:
        raise ProtocolError(
            f"'{op}' field '{key}' must be a non-negative number up to {MAX_OPTION_VALUE}", request_id, op
        )
    return int(value)


def _request_id(data: dict[str, Any]) -> RequestId | None:
    """The client's `id`, kept as the JSON value it was; anything else is refused (and not echoed)."""
    raw = data.get("id")
    if raw is None:
        return None
    if isinstance(raw, str) and len(raw) <= MAX_ID_CHARS:
        return raw
    if isinstance(raw, int) and not isinstance(raw, bool) and abs(raw) <= MAX_ID_INT:
        return raw
    raise ProtocolError(
        f"'id' must be a string of at most {MAX_ID_CHARS} characters or an integer within ±(2^63-1)"
    )


def _interface_type(
    data: dict[str, Any], key: str, kind: InterfaceKind, op: str, request_id: RequestId, required: bool
) -> str | None:
    raw = _string(data, key, op, request_id, required=required)
    if not raw:
        return None
    try:
        return normalize_interface(raw, kind)
    except ValueError:
        raise ProtocolError(
            f"invalid {kind} type {preview(raw)} (expected pkg/Type or pkg/{kind}/Type)", request_id, op
        ) from None


def _args(data: dict[str, Any], op: str, request_id: RequestId) -> dict[str, Any]:
    args = data.get("args")
    if args is None:
        return {}  # a request or goal without fields (std_srvs/srv/Trigger)
    if not isinstance(args, dict):
        raise ProtocolError(
            f"'{op}' field 'args' must be a JSON object of the request's fields", request_id, op
        )
    return args


def _compression(data: dict[str, Any], op: str, request_id: RequestId | None) -> None:
    compression = data.get("compression", "none")
    if compression not in (None, "none"):
        raise ProtocolError(
            f"compression {preview(compression)} is not supported (only 'none')", request_id, op
        )


def _timeout(data: dict[str, Any], op: str, request_id: RequestId) -> float | None:
    value = data.get("timeout")
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= MAX_CALL_TIMEOUT_S:
        raise ProtocolError(
            f"'{op}' field 'timeout' must be a number of seconds in (0, {MAX_CALL_TIMEOUT_S:g}]",
            request_id,
            op,
        )
    return float(value)


def _parse_call(op: str, data: dict[str, Any], request_id: RequestId | None) -> Request:
    """The three call ops. `fragment_size` is ignored (replies are never fragmented), as for topics."""
    if request_id is None:
        raise ProtocolError(
            f"'{op}' needs an 'id' (a string or an integer): its reply is matched by it", op=op
        )
    key = "service" if op == "call_service" else "action"
    name = _topic(data, op, request_id, key)
    try:
        _compression(data, op, request_id)
        if op == "call_service":
            service_type = _interface_type(data, "type", "srv", op, request_id, required=False)
            return CallService(
                name, _args(data, op, request_id), request_id, service_type, _timeout(data, op, request_id)
            )
        if op == "send_action_goal":
            action_type = _interface_type(data, "action_type", "action", op, request_id, required=True) or ""
            feedback = data.get("feedback", False)
            if not isinstance(feedback, bool):
                raise ProtocolError(f"'{op}' field 'feedback' must be true or false", request_id, op)
            return SendActionGoal(name, action_type, _args(data, op, request_id), request_id, feedback)
        return CancelActionGoal(name, request_id)
    except ProtocolError as error:
        error.target = name  # the call is answered as failed, under the name the client gave
        raise


def parse_request(text: str | bytes, max_depth: int = MAX_JSON_DEPTH) -> Request:
    """Parse one inbound frame; raise ProtocolError with a message fit to send back to the client."""
    data = load_json(text, max_depth)
    if not isinstance(data, dict):
        raise ProtocolError("a request must be a JSON object")
    request_id = _request_id(data)
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
        _compression(data, op, request_id)
        return Subscribe(
            _topic(data, op, request_id),
            _type(data, op, request_id, False),
            _non_negative_int(data, "throttle_rate", op, request_id),
            _non_negative_int(data, "queue_length", op, request_id),
            request_id,
        )
    if op == "unsubscribe":
        return Unsubscribe(_topic(data, op, request_id), request_id)
    if op in CALL_OPS:
        return _parse_call(op, data, request_id)
    raise ProtocolError(f"unsupported op {preview(op)}", request_id, op)


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


def _dumps(value: Any) -> str:
    return json.dumps(value, separators=(",", ":"))


def encode_service_response(service: str, request_id: RequestId, values_json: str) -> str:
    """A successful `service_response` around the already-encoded response fields (a JSON object)."""
    return (
        f'{{"op":"service_response","service":{_dumps(service)},"id":{_dumps(request_id)},'
        f'"values":{values_json},"result":true}}'
    )


def encode_service_failure(service: str, request_id: RequestId, error: str, code: str) -> str:
    """A failed call as rosbridge says it (`result` false, `values` the error text) plus our `code`."""
    frame = {"op": "service_response", "service": service, "id": request_id, "values": error, "result": False}
    return _dumps({**frame, "code": code} if code else frame)


def encode_action_feedback(action: str, request_id: RequestId, values_json: str) -> str:
    """Feedback fields (already encoded) of the goal sent with `request_id`."""
    return (
        f'{{"op":"action_feedback","action":{_dumps(action)},"id":{_dumps(request_id)},'
        f'"values":{values_json}}}'
    )


def encode_action_result(action: str, request_id: RequestId, status: int, values_json: str) -> str:
    """A goal's end with its result fields; `status` is action_msgs/GoalStatus (4 succeeded, 5 canceled,
    6 aborted). rosbridge says `result` true whenever the server sent a result, whatever the status."""
    return (
        f'{{"op":"action_result","action":{_dumps(action)},"id":{_dumps(request_id)},'
        f'"values":{values_json},"status":{int(status)},"result":true}}'
    )


def encode_action_failure(action: str, request_id: RequestId, status: int, error: str, code: str) -> str:
    """A goal that ended without a result (refused, rejected, no server): `result` false, `values` the
    error text. `status` is always present: roslibpy reads it (GoalStatus) even on failures."""
    frame: dict[str, Any] = {
        "op": "action_result",
        "action": action,
        "id": request_id,
        "values": error,
        "status": int(status),
        "result": False,
    }
    return _dumps({**frame, "code": code} if code else frame)


def encode_request(request: Request) -> str:
    """Client side: the JSON frame for a request. Raises ValueError for NaN/inf in args (not JSON)."""
    frame: dict[str, Any]
    if isinstance(request, (CallService, SendActionGoal, CancelActionGoal)):
        return json.dumps(_call_frame(request), separators=(",", ":"), allow_nan=False)
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


def _call_frame(request: CallService | SendActionGoal | CancelActionGoal) -> dict[str, Any]:
    if isinstance(request, CallService):
        frame: dict[str, Any] = {"op": "call_service", "id": request.id, "service": request.service}
        frame["args"] = request.args
        if request.type:
            frame["type"] = request.type
        if request.timeout_s is not None:
            frame["timeout"] = request.timeout_s
        return frame
    if isinstance(request, SendActionGoal):
        return {
            "op": "send_action_goal",
            "id": request.id,
            "action": request.action,
            "action_type": request.action_type,
            "args": request.args,
            "feedback": request.feedback,
        }
    return {"op": "cancel_action_goal", "id": request.id, "action": request.action}


@dataclass(frozen=True)
class Incoming:
    """What a client receives: a message on a topic, or a status."""

    topic: str
    msg: dict[str, Any]


@dataclass(frozen=True)
class ServiceReply:
    """A `service_response`: the response fields when ok, else the error text (and our code)."""

    id: RequestId
    service: str
    ok: bool
    values: dict[str, Any] | None
    error: str = ""
    code: str = ""


@dataclass(frozen=True)
class GoalFeedback:
    """An `action_feedback`: the feedback fields of the goal sent with id `id`."""

    id: RequestId
    action: str
    values: dict[str, Any]


@dataclass(frozen=True)
class GoalResult:
    """An `action_result`: `status` is action_msgs/GoalStatus (0 unknown, 4 succeeded, 5 canceled,
    6 aborted); `values` the result fields when ok, else None with the error text (and our code)."""

    id: RequestId
    action: str
    ok: bool
    status: int
    values: dict[str, Any] | None
    error: str = ""
    code: str = ""


CallReply = ServiceReply | GoalFeedback | GoalResult
REPLY_OPS = ("service_response", "action_feedback", "action_result")
MAX_GOAL_STATUS = 6  # action_msgs/GoalStatus: 0 unknown ... 6 aborted


def parse_call_reply(data: dict[str, Any]) -> CallReply:
    """Client side: a `service_response`, `action_feedback` or `action_result` object (op checked by
    the caller); ProtocolError for anything that does not follow protocol.md."""
    op = data.get("op")
    raw_id = data.get("id")
    if isinstance(raw_id, bool) or not isinstance(raw_id, (str, int)):
        raise ProtocolError(f"'{op}' from the server without a string or integer 'id'")
    key = "service" if op == "service_response" else "action"
    name = data.get(key)
    if not isinstance(name, str) or not name:
        raise ProtocolError(f"'{op}' from the server without a '{key}' name")
    values = data.get("values")
    if op == "action_feedback":
        if not isinstance(values, dict):
            raise ProtocolError("'action_feedback' from the server whose 'values' is not an object")
        return GoalFeedback(raw_id, name, values)
    result = data.get("result", True)
    if not isinstance(result, bool):
        raise ProtocolError(f"'{op}' from the server whose 'result' is not true or false")
    code = data.get("code", "")
    code = code if isinstance(code, str) else ""
    error = "" if result else (values if isinstance(values, str) else f"failed ({code or 'no reason given'})")
    if result and values is not None and not isinstance(values, dict):
        raise ProtocolError(f"successful '{op}' from the server whose 'values' is not an object")
    fields = (values or {}) if result else None
    if op == "service_response":
        return ServiceReply(raw_id, name, result, fields, error, "" if result else code)
    status = data.get("status", 0)
    if isinstance(status, bool) or not isinstance(status, int) or not 0 <= status <= MAX_GOAL_STATUS:
        raise ProtocolError(f"'action_result' from the server with status {status!r} (expected 0..6)")
    return GoalResult(raw_id, name, result, status, fields, error, "" if result else code)


def parse_server_frame(text: str | bytes) -> Incoming | Status | CallReply:
    """Client side: parse a bridge frame; raise ProtocolError for anything unexpected."""
    try:
        data = load_json(text, max_depth=256)  # ROS messages from the robot may nest deeper than requests
    except ProtocolError as error:
        raise ProtocolError(f"from server: {error}") from None
    if not isinstance(data, dict):
        raise ProtocolError("server frame is not a JSON object")
    op = data.get("op")
    if op == "publish" and isinstance(data.get("topic"), str) and isinstance(data.get("msg"), dict):
        return Incoming(data["topic"], data["msg"])
    if op in REPLY_OPS:
        return parse_call_reply(data)
    if op == "status":
        level = data.get("level", "info")
        counts = data.get("counts") or {}
        raw_id = data.get("id")
        if not isinstance(counts, dict) or not all(
            isinstance(v, int) and not isinstance(v, bool) for v in counts.values()
        ):
            raise ProtocolError("status 'counts' from server must map names to integers")
        return Status(
            level if level in ("error", "warning", "info") else "info",
            str(data.get("msg", "")),
            raw_id if isinstance(raw_id, (str, int)) and not isinstance(raw_id, bool) else None,
            str(data.get("code", "")),
            str(data.get("topic", "")),
            {str(k): v for k, v in counts.items()},
        )
    raise ProtocolError(f"unexpected server frame op {op!r}")
