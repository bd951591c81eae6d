"""The JSON Schema the model sees, generated from a ROS interface's fields and the file's bounds.

Only a small subset of JSON Schema is produced (type, properties, required, additionalProperties
false, items, minItems/maxItems, minimum/maximum, minLength/maxLength, enum, contentEncoding
base64, description), the subset tools/arguments.py validates.
"""

from __future__ import annotations

import math
from typing import Any

from by_your_command.tools.config import ArgumentConfig
from by_your_command.tools.interface_types import (
    BYTE_KINDS,
    FLOAT32_MAX,
    INT_RANGES,
    Constant,
    Field,
    Message,
)

MAX_SCHEMA_DEPTH = 24
MAX_CONSTANTS_SHOWN = 40
CONFIRMED_SCHEMA: dict[str, Any] = {
    "type": "boolean",
    "description": "true only after the user said yes to doing this; ask them first",
}


class SchemaProblem(ValueError):
    """A field the schema cannot express, or a bound outside its type's range."""


def base64_chars(count: int) -> int:
    return 4 * math.ceil(count / 3)


def constants_text(constants: tuple[Constant, ...]) -> str:
    shown = ", ".join(f"{c.name}={c.value!r}" for c in constants[:MAX_CONSTANTS_SHOWN])
    more = ", …" if len(constants) > MAX_CONSTANTS_SHOWN else ""
    return f"constants: {shown}{more}" if constants else ""


def message_schema(message: Message, depth: int = 0) -> dict[str, Any]:
    """An object of the message's fields, none required (absent fields keep their ROS defaults)."""
    if depth > MAX_SCHEMA_DEPTH:
        raise SchemaProblem(f"{message.type} is nested more than {MAX_SCHEMA_DEPTH} deep")
    schema: dict[str, Any] = {
        "type": "object",
        "properties": {field.name: field_schema(field, depth + 1) for field in message.fields},
        "additionalProperties": False,
    }
    description = _message_description(message)
    if description:
        schema["description"] = description
    return schema


def _message_description(message: Message) -> str:
    if message.type in ("builtin_interfaces/msg/Time", "builtin_interfaces/msg/Duration"):
        return "seconds (sec) and nanoseconds (nanosec)"
    return constants_text(message.constants)


def field_schema(field: Field, depth: int = 0) -> dict[str, Any]:
    if field.container and field.kind in BYTE_KINDS:
        schema: dict[str, Any] = {"type": "string", "contentEncoding": "base64"}
        if field.size is not None:
            schema["maxLength"] = base64_chars(field.size)
            if field.container == "array":
                schema["minLength"] = schema["maxLength"]
        many = f"exactly {field.size}" if field.container == "array" else f"at most {field.size}"
        schema["description"] = f"{many if field.size is not None else ''} bytes, base64".strip()
        return schema
    element = _element_schema(field, depth)
    if not field.container:
        return element
    schema = {"type": "array", "items": element}
    if field.size is not None:
        schema["maxItems"] = field.size
        if field.container == "array":
            schema["minItems"] = field.size
    return schema


def _element_schema(field: Field, depth: int) -> dict[str, Any]:
    kind = field.kind
    if kind == "message":
        if field.message is None:
            raise SchemaProblem(f"field {field.name!r}: its message type is not described")
        return message_schema(field.message, depth)
    if kind == "boolean":
        return {"type": "boolean"}
    if kind in INT_RANGES:
        low, high = INT_RANGES[kind]
        return {"type": "integer", "minimum": low, "maximum": high}
    if kind == "float":
        return {"type": "number", "minimum": -FLOAT32_MAX, "maximum": FLOAT32_MAX}
    if kind == "double":
        return {"type": "number"}
    if kind in ("string", "wstring"):
        schema: dict[str, Any] = {"type": "string"}
        if field.string_bound is not None:
            schema["maxLength"] = field.string_bound
        return schema
    raise SchemaProblem(f"field {field.name!r}: {field.ros_type} fields are not supported")


def argument_schema(field: Field, argument: ArgumentConfig, parent: Message) -> dict[str, Any]:
    """The schema of a model-filled argument: its field's, tightened by the file's bounds (which
    must lie inside the type's range)."""
    schema = field_schema(field)
    _tighten(schema, field, argument)
    notes = [argument.description]
    if not field.container and field.kind != "message":
        related = tuple(c for c in parent.constants if _fits(c, field.kind))
        notes.append(constants_text(related))
    notes.append(schema.get("description", ""))
    description = "; ".join(note for note in notes if note)
    if description:
        schema["description"] = description
    return schema


def _fits(constant: Constant, kind: str) -> bool:
    value = constant.value
    if kind in INT_RANGES:
        return isinstance(value, int) and not isinstance(value, bool)
    if kind in ("float", "double"):
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind in ("string", "wstring"):
        return isinstance(value, str)
    return kind == "boolean" and isinstance(value, bool)


def _tighten(schema: dict[str, Any], field: Field, argument: ArgumentConfig) -> None:
    for key, value in (("minimum", argument.minimum), ("maximum", argument.maximum)):
        if value is None:
            continue
        if schema["type"] not in ("integer", "number"):
            raise SchemaProblem(f"{key}: {field.name} is a {field.ros_type} field, not a number")
        if schema["type"] == "integer":
            if value != int(value):
                raise SchemaProblem(f"{key}: {field.name} is a {field.ros_type} field: {value} is not whole")
            value = int(value)
        low, high = schema.get("minimum", -math.inf), schema.get("maximum", math.inf)
        if not low <= value <= high:
            raise SchemaProblem(f"{key}: {value} is outside the {field.ros_type} range [{low}, {high}]")
        schema[key] = value
    if argument.max_length is not None:
        if field.container or schema["type"] != "string":
            raise SchemaProblem(f"max_length: {field.name} is a {field.ros_type} field, not a string")
        _lower(schema, "maxLength", argument.max_length, field, "max_length")
    if argument.max_items is not None:
        if not field.container:
            raise SchemaProblem(f"max_items: {field.name} is a {field.ros_type} field, not an array")
        if field.container == "array" and argument.max_items != field.size:
            raise SchemaProblem(f"max_items: {field.name} always has {field.size} elements")
        if schema["type"] == "string":  # bytes as base64
            _lower(schema, "maxLength", base64_chars(argument.max_items), field, "max_items")
            schema["description"] = f"at most {argument.max_items} bytes, base64"
        else:
            _lower(schema, "maxItems", argument.max_items, field, "max_items")


def _lower(schema: dict[str, Any], key: str, value: int, field: Field, name: str) -> None:
    if key in schema and value > schema[key]:
        raise SchemaProblem(f"{name}: {value} is beyond the bound of {field.ros_type}")
    schema[key] = value


def choices_schema(names: list[str], description: str) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "string", "enum": names}
    if description:
        schema["description"] = description
    return schema


def parameters_schema(
    properties: dict[str, dict[str, Any]], required: list[str], confirm: bool
) -> dict[str, Any]:
    """The tool's top-level object (an empty one for tools without arguments)."""
    properties = dict(properties)
    required = list(required)
    if confirm:
        properties["confirmed"] = dict(CONFIRMED_SCHEMA)
        required.append("confirmed")
    return {"type": "object", "properties": properties, "required": required, "additionalProperties": False}
