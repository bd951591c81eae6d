"""Wire helpers for the OpenAI Realtime emulator: ids, the error envelope, checked field access.

Client frames are untrusted: every field the emulator uses is read through these getters, which
raise `ClientEventError` (sent back as the documented `error` event) instead of crashing.
"""

from __future__ import annotations

import base64
import binascii
import itertools
import json
from collections.abc import Mapping
from typing import Any

JsonObject = dict[str, Any]

_counter = itertools.count(1)


def new_id(prefix: str) -> str:
    """Ids shaped like the real ones (prefix_ + 22 characters), unique within the process."""
    return f"{prefix}_emu{next(_counter):019d}"


class ClientEventError(Exception):
    """A client event the server refuses; becomes an `error` event, the session stays open."""

    def __init__(self, code: str, message: str, param: str | None = None) -> None:
        super().__init__(message)
        self.code, self.message, self.param = code, message, param


def error_event(
    code: str, message: str, param: str | None = None, client_event_id: str | None = None
) -> JsonObject:
    return {
        "type": "error",
        "event_id": new_id("event"),
        "error": {
            "type": "invalid_request_error",
            "code": code,
            "message": message,
            "param": param,
            "event_id": client_event_id,
        },
    }


def parse_client_frame(frame: str | bytes, max_depth: int = 32) -> JsonObject:
    """The JSON object of one text frame, with a string `type`; ClientEventError otherwise."""
    if isinstance(frame, bytes):
        raise ClientEventError("invalid_request_error", "Binary frames are not supported; send JSON text.")
    try:
        parsed = json.loads(frame)
    except (ValueError, RecursionError) as error:
        raise ClientEventError("invalid_json", f"The server could not parse the JSON body: {error}") from None
    if not isinstance(parsed, dict):
        raise ClientEventError("invalid_request_error", "Expected a JSON object with a `type`.")
    if _depth(parsed) > max_depth:
        raise ClientEventError("invalid_request_error", f"JSON nested deeper than {max_depth} levels.")
    if not isinstance(parsed.get("type"), str):
        raise ClientEventError("missing_required_parameter", "Missing required parameter: 'type'.", "type")
    event_id = parsed.get("event_id")
    if event_id is not None and not isinstance(event_id, str):
        raise ClientEventError("invalid_type", "Invalid type for 'event_id': expected a string.", "event_id")
    return parsed


def _depth(value: object) -> int:
    stack: list[tuple[object, int]] = [(value, 1)]
    deepest = 0
    while stack:
        node, depth = stack.pop()
        deepest = max(deepest, depth)
        children = node.values() if isinstance(node, dict) else node if isinstance(node, list) else ()
        stack.extend((child, depth + 1) for child in children if isinstance(child, (dict, list)))
    return deepest


def field_str(event: Mapping[str, Any], key: str, param: str, *, required: bool = True) -> str | None:
    value = event.get(key)
    if value is None:
        if required:
            raise ClientEventError(
                "missing_required_parameter", f"Missing required parameter: '{param}'.", param
            )
        return None
    if not isinstance(value, str):
        raise ClientEventError("invalid_type", f"Invalid type for '{param}': expected a string.", param)
    return value


def required_str(event: Mapping[str, Any], key: str, param: str) -> str:
    value = field_str(event, key, param)
    assert value is not None
    return value


def field_int(event: Mapping[str, Any], key: str, param: str) -> int:
    value = event.get(key)
    if value is None:
        raise ClientEventError("missing_required_parameter", f"Missing required parameter: '{param}'.", param)
    if not isinstance(value, int) or isinstance(value, bool):
        raise ClientEventError("invalid_type", f"Invalid type for '{param}': expected an integer.", param)
    return value


def field_object(event: Mapping[str, Any], key: str, param: str, *, required: bool = True) -> JsonObject:
    value = event.get(key)
    if value is None and not required:
        return {}
    if value is None:
        raise ClientEventError("missing_required_parameter", f"Missing required parameter: '{param}'.", param)
    if not isinstance(value, dict):
        raise ClientEventError("invalid_type", f"Invalid type for '{param}': expected an object.", param)
    return value


def decode_pcm(value: str, param: str) -> bytes:
    try:
        pcm = base64.b64decode(value, validate=True)
    except (binascii.Error, ValueError):
        raise ClientEventError("invalid_value", f"Invalid value for '{param}': not base64.", param) from None
    if len(pcm) % 2:
        raise ClientEventError(
            "invalid_value", f"Invalid value for '{param}': odd number of PCM16 bytes.", param
        )
    return pcm
