"""Describe an installed ROS interface (pkg/msg/T, pkg/srv/T, pkg/action/T) as plain data.

Reads the generated Python classes (`SLOT_TYPES` from rosidl_parser, the field names, upper-case
constants) and returns tools/interface_types' frozen tree, so the catalog code needs no ROS.
"""

from __future__ import annotations

import functools
import importlib
import re
from typing import Any

from rosidl_parser import definition  # type: ignore[import-untyped]

from by_your_command.tools.interface_types import (
    PART_NAMES,
    Constant,
    Container,
    Field,
    Interface,
    InterfaceError,
    InterfaceKind,
    Message,
)

MAX_NESTING = 24  # ROS types cannot recurse; deeper than this is a broken package, not a message
_NAME = r"[A-Za-z][A-Za-z0-9_]*"
_TYPE_RE = re.compile(rf"({_NAME})/(?:(msg|srv|action)/)?({_NAME})")
# IDL names of the integer types .msg files never produce but IDL files may
_IDL_INTS = {
    "short": "int16",
    "long": "int32",
    "long long": "int64",
    "unsigned short": "uint16",
    "unsigned long": "uint32",
    "unsigned long long": "uint64",
}
_ATTRIBUTES = {"message": None, "request": "Request", "response": "Response"}
_ATTRIBUTES |= {"goal": "Goal", "result": "Result", "feedback": "Feedback"}


def describe(type_name: str) -> Interface:
    """`geometry_msgs/msg/PoseStamped` (or `pkg/T`), `pkg/srv/T`, `pkg/action/T` → its parts' field
    trees; InterfaceError when the name is malformed or the type is not installed."""
    match = _TYPE_RE.fullmatch(type_name) if isinstance(type_name, str) and len(type_name) <= 256 else None
    if match is None:
        raise InterfaceError(
            f"invalid interface type {type_name!r} (expected pkg/msg/T, pkg/srv/T or pkg/action/T)"
        )
    package, middle, name = match.groups()
    kind: InterfaceKind = middle or "msg"  # type: ignore[assignment]
    normalized = f"{package}/{kind}/{name}"
    top = _import(package, kind, name, normalized)
    parts = []
    for part in PART_NAMES[kind]:
        attribute = _ATTRIBUTES[part]
        cls = top if attribute is None else getattr(top, attribute, None)
        if cls is None:
            raise InterfaceError(f"{normalized} has no {attribute} (is it really a {kind}?)")
        parts.append((part, _message(cls, 0)))
    return Interface(normalized, kind, tuple(parts))


def _import(package: str, kind: str, name: str, normalized: str) -> Any:
    try:
        module = importlib.import_module(f"{package}.{kind}")
    except ImportError:
        raise InterfaceError(f"{normalized} is not installed (no Python module {package}.{kind})") from None
    cls = getattr(module, name, None)
    if cls is None:
        raise InterfaceError(f"{normalized} is not installed ({package}.{kind} has no {name})")
    return cls


@functools.lru_cache(maxsize=512)
def _message(cls: Any, depth: int) -> Message:
    if depth > MAX_NESTING:
        raise InterfaceError(f"{cls.__name__}: messages nested more than {MAX_NESTING} deep")
    try:
        field_types: dict[str, str] = cls.get_fields_and_field_types()
        slots = tuple(cls.SLOT_TYPES)
    except AttributeError:
        raise InterfaceError(f"{cls!r} is not a generated ROS message class") from None
    if len(slots) != len(field_types):
        raise InterfaceError(f"{cls.__name__}: field names and slot types disagree")
    fields = tuple(
        _field(name, ros_type, slot, depth)
        for (name, ros_type), slot in zip(field_types.items(), slots, strict=True)
    )
    return Message(_type_of(cls), fields, _constants(cls, set(field_types)))


def _type_of(cls: Any) -> str:
    """`geometry_msgs.msg._pose_stamped` + `PoseStamped` → `geometry_msgs/msg/PoseStamped`."""
    module = cls.__module__.split(".")
    return f"{module[0]}/{module[1] if len(module) > 1 else 'msg'}/{cls.__name__}"


def _field(name: str, ros_type: str, slot: Any, depth: int) -> Field:
    container: Container = ""
    size: int | None = None
    if isinstance(slot, definition.Array):
        container, size, slot = "array", int(slot.size), slot.value_type
    elif isinstance(slot, definition.BoundedSequence):
        container, size, slot = "sequence", int(slot.maximum_size), slot.value_type
    elif isinstance(slot, definition.UnboundedSequence):
        container, slot = "sequence", slot.value_type
    string_bound: int | None = None
    message: Message | None = None
    if isinstance(slot, definition.BasicType):
        kind = _IDL_INTS.get(slot.typename, slot.typename)
    elif isinstance(slot, (definition.BoundedString, definition.BoundedWString)):
        kind = "string" if isinstance(slot, definition.BoundedString) else "wstring"
        string_bound = int(slot.maximum_size)
    elif isinstance(slot, definition.UnboundedString):
        kind = "string"
    elif isinstance(slot, definition.UnboundedWString):
        kind = "wstring"
    elif isinstance(slot, definition.NamespacedType):
        kind = "message"
        nested = _import(slot.namespaces[0], slot.namespaces[-1], slot.name, "/".join(slot.namespaced_name()))
        message = _message(nested, depth + 1)
    else:
        raise InterfaceError(f"field {name!r}: unsupported slot type {type(slot).__name__}")
    return Field(name, kind, ros_type, container, size, string_bound, message)


def _constants(cls: Any, fields: set[str]) -> tuple[Constant, ...]:
    """Upper-case class attributes with a plain value (`STATUS_FIX = 0`); `X__DEFAULT` are defaults."""
    found = []
    for attribute in dir(cls):
        if not attribute.isupper() or "__" in attribute or attribute in fields or attribute.startswith("_"):
            continue
        value = getattr(cls, attribute, None)
        if isinstance(value, (bool, int, float, str)):
            found.append(Constant(attribute, value))
    return tuple(found)
