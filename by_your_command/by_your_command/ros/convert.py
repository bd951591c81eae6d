"""Any ROS message ⇄ JSON-ready dicts, with rosbridge's conventions.

Services and actions are messages too: their parts (`pkg/srv/T` Request/Response, `pkg/action/T`
Goal/Result/Feedback) convert the same way (`part_class`).

Nested messages become objects, arrays lists, Time/Duration `{sec, nanosec}` (they are ordinary
messages), and uint8[]/char[] (and fixed uint8[N]) base64 strings, like rosbridge. Inbound dicts are
checked field by field: unknown fields, wrong JSON types and out-of-range numbers are errors with
the field's path, never silently ignored. Absent fields keep their defaults (rosbridge does that).
"""

from __future__ import annotations

import array
import base64
import binascii
import importlib
import json
import math
import re
from typing import Any, Literal

from by_your_command.bridge.protocol import InterfaceKind, normalize_interface, normalize_type
from by_your_command.tools.interface_types import INT_RANGES

Part = Literal["request", "response", "goal", "result", "feedback"]
_PART_KINDS: dict[str, tuple[InterfaceKind, str]] = {
    "request": ("srv", "Request"),
    "response": ("srv", "Response"),
    "goal": ("action", "Goal"),
    "result": ("action", "Result"),
    "feedback": ("action", "Feedback"),
}

_SEQUENCE_RE = re.compile(r"^sequence<(.+?)(?:, ?(\d+))?>$")
_ARRAY_RE = re.compile(r"^(.+)\[(\d+)\]$")
_BOUNDED_STRING_RE = re.compile(r"^w?string<(\d+)>$")
_FLOATS = {"float", "double"}
_BYTE_ELEMENTS = {"uint8", "char", "octet"}
# array.array typecodes rclpy uses for numeric sequences: fast bulk conversion
_TYPECODES = {
    "int8": "b",
    "uint8": "B",
    "int16": "h",
    "uint16": "H",
    "int32": "i",
    "uint32": "I",
    "int64": "q",
    "uint64": "Q",
    "float": "f",
    "double": "d",
}


_SHOW_CHARS = 40
# Typecodes whose array.array() checks exactly what the slow path checks (int range); float32 ('f')
# is not among them: array('f') turns 1e300 into inf where the field setter would refuse it.
_FAST_INT_TYPECODES = {"b", "B", "h", "H", "i", "I", "q", "Q"}


class ConversionError(ValueError):
    pass


def _show(value: Any) -> str:
    """A client value quoted in an error: short whatever it was (errors travel back in replies)."""
    if isinstance(value, (dict, list)):
        return f"<{'object' if isinstance(value, dict) else 'list'} of {len(value)}>"
    text = repr(value)
    return text if len(text) <= _SHOW_CHARS else f"{text[:_SHOW_CHARS]}… ({len(text)} chars)"


def message_class(type_name: str) -> Any:
    """`std_msgs/msg/String` (or `std_msgs/String`) → the generated Python class."""
    package, _, name = normalize_type(type_name).split("/")
    try:
        module = importlib.import_module(f"{package}.msg")
        return getattr(module, name)
    except (ImportError, AttributeError):
        raise ConversionError(f"message type {type_name!r} is not installed") from None


def interface_class(type_name: str, kind: InterfaceKind) -> Any:
    """`std_srvs/srv/Trigger` (kind "srv") or `nav2_msgs/action/NavigateToPose` (kind "action"), also
    without the middle part, → the generated Python class (what rclpy's clients take)."""
    try:
        package, _, name = normalize_interface(type_name, kind).split("/")
    except ValueError as error:
        raise ConversionError(str(error)) from None
    try:
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ImportError, AttributeError):
        raise ConversionError(f"{kind} type {type_name!r} is not installed") from None


def part_class(type_name: str, part: Part) -> Any:
    """The message class of one part of a service (request, response) or action (goal, result,
    feedback): `part_class("std_srvs/srv/Trigger", "request")` is `Trigger.Request`."""
    kind, attribute = _PART_KINDS[part]
    return getattr(interface_class(type_name, kind), attribute)


def _fields(cls: Any) -> dict[str, str]:
    fields: dict[str, str] = cls.get_fields_and_field_types()
    return fields


# --- ROS → JSON ----------------------------------------------------------------------------------


def to_dict(msg: Any) -> dict[str, Any]:
    return {name: _value_to_json(getattr(msg, name), kind) for name, kind in _fields(type(msg)).items()}


def to_json(msg: Any) -> str:
    """The message as compact JSON object text (non-finite floats are null, as in `to_dict`)."""
    return json.dumps(to_dict(msg), separators=(",", ":"), allow_nan=False)


def _value_to_json(value: Any, kind: str) -> Any:
    element, is_sequence = _element_kind(kind)
    if is_sequence:
        if element in _BYTE_ELEMENTS:
            raw = bytes(value) if not isinstance(value, list) else b"".join(value)
            return base64.b64encode(raw).decode("ascii")
        if element in _FLOATS:
            return [_float_to_json(item) for item in value]
        if element in _TYPECODES or element == "boolean":
            return (
                value.tolist() if hasattr(value, "tolist") else [_scalar_to_json(v, element) for v in value]
            )
        return [_value_to_json(item, element) for item in value]
    return _scalar_to_json(value, kind)


def _scalar_to_json(value: Any, kind: str) -> Any:
    if kind in _FLOATS:
        return _float_to_json(value)
    if kind in ("octet", "char") and isinstance(value, (bytes, str)):
        return ord(value) if len(value) == 1 else 0
    if "/" in kind:
        return to_dict(value)
    return value  # bool, int, str


def _float_to_json(value: float) -> Any:
    return float(value) if math.isfinite(value) else None  # JSON has no NaN/inf (rosbridge: null)


def _element_kind(kind: str) -> tuple[str, bool]:
    sequence = _SEQUENCE_RE.match(kind)
    if sequence:
        return sequence.group(1), True
    fixed = _ARRAY_RE.match(kind)
    if fixed:
        return fixed.group(1), True
    return kind, False


# --- JSON → ROS ----------------------------------------------------------------------------------


def from_dict(cls: Any, data: dict[str, Any], path: str = "") -> Any:
    """Build a `cls` message from `data`; ConversionError names the offending field."""
    if not isinstance(data, dict):
        raise ConversionError(f"{path or 'message'}: expected an object, got {type(data).__name__}")
    fields = _fields(cls)
    unknown = sorted(set(data) - set(fields))
    if unknown:
        shown = ", ".join(_show(name) for name in unknown[:5]) + (", …" if len(unknown) > 5 else "")
        raise ConversionError(f"{path or cls.__name__}: unknown field(s) {shown}")
    msg = cls()
    for name, value in data.items():
        field_path = f"{path}.{name}" if path else name
        converted = _value_from_json(value, fields[name], field_path)
        try:
            setattr(msg, name, converted)
        except (AssertionError, TypeError, ValueError) as error:
            raise ConversionError(f"{field_path}: {error or 'invalid value'}") from None
    return msg


def _value_from_json(value: Any, kind: str, path: str) -> Any:
    sequence = _SEQUENCE_RE.match(kind)
    fixed = _ARRAY_RE.match(kind)
    if sequence or fixed:
        element = (sequence or fixed).group(1)  # type: ignore[union-attr]
        bound = int(sequence.group(2)) if sequence and sequence.group(2) else None
        length = int(fixed.group(2)) if fixed else None
        items = _sequence_from_json(value, element, path)
        count = len(items)
        if bound is not None and count > bound:
            raise ConversionError(f"{path}: at most {bound} elements allowed, got {count}")
        if length is not None and count != length:
            raise ConversionError(f"{path}: exactly {length} elements required, got {count}")
        return items
    return _scalar_from_json(value, kind, path)


def _sequence_from_json(value: Any, element: str, path: str) -> Any:
    if element in _BYTE_ELEMENTS and isinstance(value, str):
        try:
            raw = base64.b64decode(value, validate=True)
        except (binascii.Error, ValueError):
            raise ConversionError(f"{path}: not valid base64") from None
        return [bytes([b]) for b in raw] if element == "octet" else array.array("B", raw)
    if not isinstance(value, list):
        raise ConversionError(
            f"{path}: expected a list" + (" or base64 string" if element in _BYTE_ELEMENTS else "")
        )
    typecode = _TYPECODES.get(element)
    if typecode in _FAST_INT_TYPECODES and element != "octet" and set(map(type, value)) <= {int}:
        try:  # C speed for audio; on failure the item-by-item path names the offending element
            return array.array(typecode, value)
        except OverflowError:
            pass
    items = [_scalar_from_json(item, element, f"{path}[{index}]") for index, item in enumerate(value)]
    return array.array(typecode, items) if typecode and element != "octet" else items


def _scalar_from_json(value: Any, kind: str, path: str) -> Any:
    if "/" in kind:
        return from_dict(message_class(kind), value, path)
    if kind == "boolean":
        if not isinstance(value, bool):
            raise ConversionError(f"{path}: expected true/false, got {_show(value)}")
        return value
    if kind in _FLOATS:
        if value is None:
            return math.nan
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConversionError(f"{path}: expected a number, got {_show(value)}")
        return float(value)
    if kind in INT_RANGES:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConversionError(f"{path}: expected an integer, got {_show(value)}")
        low, high = INT_RANGES[kind]
        if not low <= value <= high:
            raise ConversionError(f"{path}: {_show(value)} is out of range for {kind} [{low}, {high}]")
        return bytes([value]) if kind == "octet" else value
    if kind in ("string", "wstring") or _BOUNDED_STRING_RE.match(kind):
        if not isinstance(value, str):
            raise ConversionError(f"{path}: expected a string, got {_show(value)}")
        return value
    raise ConversionError(f"{path}: unsupported field type {kind}")
