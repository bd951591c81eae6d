"""Client side of the wire: parse bridge frames defensively, encode publishes strictly.

The bridge is trusted no more than any other input: a frame that is not what protocol.md says is a
`ServerFrameError` (counted and logged by the client), never an exception that ends a loop.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from by_your_command.bridge.protocol import REPLY_OPS, CallReply, ProtocolError, Status, parse_call_reply

# A count above this is not a count (JSON numbers beyond 2**53 are not even exact in JavaScript).
MAX_COUNT = 2**53


class ServerFrameError(ValueError):
    """A frame from the bridge that does not follow the protocol."""


@dataclass(frozen=True, slots=True)
class PublishFrame:
    topic: str
    msg: dict[str, Any]


@dataclass(frozen=True)
class StatusFrame:
    status: Status
    defects: tuple[str, ...] = ()  # fields that were malformed and left out (the rest is usable)


def parse_server_frame(text: str | bytes) -> PublishFrame | StatusFrame | CallReply:
    try:
        data = json.loads(text)
    except (UnicodeDecodeError, ValueError, RecursionError) as error:
        raise ServerFrameError(f"malformed JSON from the bridge: {_short(error)}") from None
    if not isinstance(data, dict):
        raise ServerFrameError(f"a bridge frame must be a JSON object, got {type(data).__name__}")
    op = data.get("op")
    if op == "publish":
        topic, msg = data.get("topic"), data.get("msg")
        if not isinstance(topic, str) or not topic:
            raise ServerFrameError("'publish' from the bridge without a topic name")
        if not isinstance(msg, dict):
            raise ServerFrameError(f"'publish' on {_short(topic)!r} whose 'msg' is not an object")
        return PublishFrame(topic, msg)
    if op == "status":
        return _status(data)
    if op in REPLY_OPS:
        try:
            return parse_call_reply(data)
        except ProtocolError as error:
            raise ServerFrameError(_short(str(error), 200)) from None
    raise ServerFrameError(f"unexpected op {_short(op)!r} from the bridge")


def _status(data: dict[str, Any]) -> StatusFrame:
    defects: list[str] = []
    level = data.get("level", "info")
    if level not in ("error", "warning", "info"):
        defects.append(f"level {_short(level)!r}")
        level = "error"  # an unknown level is not reassuring: treat it as the worst
    raw_id = data.get("id")
    if raw_id is not None and (isinstance(raw_id, bool) or not isinstance(raw_id, (str, int))):
        defects.append(f"id {_short(raw_id)!r}")
        raw_id = None
    counts: dict[str, int] = {}
    raw_counts = data.get("counts")
    if isinstance(raw_counts, dict):
        for key, value in raw_counts.items():
            count = _count(value)
            if count is None:
                defects.append(f"counts[{_short(key)!r}] = {_short(value)!r}")
            else:
                counts[key] = count
    elif raw_counts is not None:
        defects.append(f"counts is {type(raw_counts).__name__}, not an object")
    status = Status(
        level,
        _text(data.get("msg"), "msg", defects),
        raw_id,  # exactly as the client sent it (a string or an integer)
        _text(data.get("code"), "code", defects),
        _text(data.get("topic"), "topic", defects),
        counts,
    )
    return StatusFrame(status, tuple(defects))


def _count(value: Any) -> int | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        value = int(value)
    if isinstance(value, int) and 0 <= value <= MAX_COUNT:
        return value
    return None


def _text(value: Any, name: str, defects: list[str]) -> str:
    if value is None:
        return ""
    if not isinstance(value, str):
        defects.append(f"{name} is {type(value).__name__}, not a string")
        return _short(value)
    return value


def _short(value: Any, limit: int = 80) -> str:
    """Bridge text quoted in our logs: bounded, so a hostile frame cannot flood them."""
    if isinstance(value, (dict, list)):
        return f"<{type(value).__name__} of {len(value)} items>"
    text = value if isinstance(value, str) else repr(value)
    return text if len(text) <= limit else f"{text[:limit]}…({len(text)} chars)"


def encode_publish(topic: str, msg: dict[str, Any], request_id: str | int | None = None) -> str:
    """A `publish` request. NaN/inf are refused here (ValueError): JSON has neither, and the
    bridge would only answer with a status error after the fact."""
    frame: dict[str, Any] = {"op": "publish", "topic": topic, "msg": msg}
    if request_id is not None:
        frame["id"] = request_id
    return json.dumps(frame, separators=(",", ":"), allow_nan=False)
