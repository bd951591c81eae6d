"""Wire helpers for the Gemini Live emulator: close codes, checked field access, base64, JSON limits.

Client frames are untrusted. Proto-JSON accepts camelCase and snake_case field names (the Python
SDK mixes both) and blob data in either base64 alphabet (the SDK sends URL-safe), so every read goes
through `field_value()`. A frame the real server would refuse raises `WireError`, which the server turns
into a WebSocket close: Gemini reports errors as close frames, never as JSON events.
"""

from __future__ import annotations

import base64
import binascii
import json
import re
from collections.abc import Mapping
from typing import Any, Final

JsonObject = dict[str, Any]

# Close codes the real server uses (protocols.md B.1).
CLOSE_NORMAL: Final = 1000
CLOSE_INVALID_ARGUMENT: Final = 1007  # bad setup or frame, invalid API key, refused resumption
CLOSE_POLICY: Final = 1008  # no API key, unknown model or method
CLOSE_INTERNAL: Final = 1011  # deadline expired (the ~58-minute close), internal errors

INVALID_ARGUMENT = "Request contains an invalid argument."
DEADLINE_EXPIRED = "Deadline expired before operation could complete."
MAX_CLOSE_REASON_BYTES = 123  # RFC 6455: a close frame's reason fits in 123 bytes

CLIENT_MESSAGE_KINDS = ("setup", "clientContent", "realtimeInput", "toolResponse")


class WireError(Exception):
    """A client frame the server refuses: the connection closes with `code` and `reason`."""

    def __init__(self, reason: str, code: int = CLOSE_INVALID_ARGUMENT) -> None:
        super().__init__(reason)
        self.code, self.reason = code, reason


def close_reason(text: str) -> str:
    """`text` cut to what a close frame can carry (whole UTF-8 characters only)."""
    data = text.encode("utf-8")[:MAX_CLOSE_REASON_BYTES]
    return data.decode("utf-8", errors="ignore")


def snake(camel: str) -> str:
    return re.sub(r"(?<!^)([A-Z])", lambda match: "_" + match.group(1).lower(), camel)


def field_value(obj: Mapping[str, Any], camel: str) -> Any:
    """The value of `camel` given in camelCase or snake_case (None when absent)."""
    if camel in obj:
        return obj[camel]
    return obj.get(snake(camel))


def obj_field(obj: Mapping[str, Any], camel: str, where: str) -> JsonObject | None:
    value = field_value(obj, camel)
    if value is not None and not isinstance(value, dict):
        raise WireError(f"{INVALID_ARGUMENT} '{where}.{camel}' must be an object.")
    return value


def str_field(obj: Mapping[str, Any], camel: str, where: str) -> str | None:
    value = field_value(obj, camel)
    if value is not None and not isinstance(value, str):
        raise WireError(f"{INVALID_ARGUMENT} '{where}.{camel}' must be a string.")
    return value


def bool_field(obj: Mapping[str, Any], camel: str, where: str) -> bool:
    value = field_value(obj, camel)
    if value is not None and not isinstance(value, bool):
        raise WireError(f"{INVALID_ARGUMENT} '{where}.{camel}' must be a boolean.")
    return bool(value)


def list_field(obj: Mapping[str, Any], camel: str, where: str) -> list[Any]:
    value = field_value(obj, camel)
    if value is None:
        return []
    if not isinstance(value, list):
        raise WireError(f"{INVALID_ARGUMENT} '{where}.{camel}' must be a list.")
    return value


def decode_blob(data: object, where: str) -> bytes:
    """Standard or URL-safe base64 (a plain b64decode would silently drop '-' and '_')."""
    if not isinstance(data, str):
        raise WireError(f"{INVALID_ARGUMENT} '{where}.data' must be a base64 string.")
    text = data.replace("-", "+").replace("_", "/")
    try:
        return base64.b64decode(text + "=" * (-len(text) % 4), validate=True)
    except (binascii.Error, ValueError):
        raise WireError(f"{INVALID_ARGUMENT} '{where}.data' is not base64.") from None


def parse_client_frame(frame: str | bytes, max_depth: int = 32) -> tuple[str, JsonObject]:
    """(kind, body) of one client message: exactly one of setup, clientContent, realtimeInput,
    toolResponse, in either casing. Text or binary frames (both carry UTF-8 JSON)."""
    try:
        message = json.loads(frame)
    except (ValueError, RecursionError):
        raise WireError(f"{INVALID_ARGUMENT} The frame is not JSON.") from None
    if not isinstance(message, dict):
        raise WireError(f"{INVALID_ARGUMENT} Expected a JSON object.")
    if _depth(message) > max_depth:
        raise WireError(f"{INVALID_ARGUMENT} JSON nested deeper than {max_depth} levels.")
    found = [kind for kind in CLIENT_MESSAGE_KINDS if field_value(message, kind) is not None]
    if len(found) != 1 or len(message) != 1:
        raise WireError(
            f"{INVALID_ARGUMENT} A message needs exactly one of {', '.join(CLIENT_MESSAGE_KINDS)}."
        )
    kind = found[0]
    body = field_value(message, kind)
    if not isinstance(body, dict):
        raise WireError(f"{INVALID_ARGUMENT} '{kind}' must be an object.")
    return kind, body


def _depth(value: object) -> int:
    stack: list[tuple[object, int]] = [(value, 1)]
    deepest = 0
    while stack:
        node, depth = stack.pop()
        deepest = max(deepest, depth)
        children = node.values() if isinstance(node, dict) else node if isinstance(node, list) else ()
        stack.extend((child, depth + 1) for child in children if isinstance(child, (dict, list)))
    return deepest


_RATE = re.compile(r"rate=(\d+)")


def pcm_rate(mime_type: str, default: int = 16_000) -> int:
    """The sample rate an `audio/pcm;rate=N` MIME type declares (16 kHz when it declares none)."""
    match = _RATE.search(mime_type)
    return int(match.group(1)) if match else default


def duration_text(seconds: float) -> str:
    """A protobuf Duration in JSON ("5s", "0.5s")."""
    return f"{seconds:g}s"
