"""JSON Schema generation: every field kind, nesting, arrays, bounds from the type and the file."""

from __future__ import annotations

from typing import Any

import pytest

from by_your_command.ros.interfaces import describe
from by_your_command.tools.config import ArgumentConfig
from by_your_command.tools.interface_types import FLOAT32_MAX, Constant, Field, Message
from by_your_command.tools.schema import (
    SchemaProblem,
    argument_schema,
    choices_schema,
    field_schema,
    message_schema,
    parameters_schema,
)

pytestmark = pytest.mark.unit

EMPTY = Message("p/msg/Empty")


def scalar(kind: str, **extra: Any) -> Field:
    return Field("x", kind, kind, **extra)


@pytest.mark.parametrize(
    ("field", "schema"),
    [
        (scalar("boolean"), {"type": "boolean"}),
        (scalar("int8"), {"type": "integer", "minimum": -128, "maximum": 127}),
        (scalar("uint8"), {"type": "integer", "minimum": 0, "maximum": 255}),
        (scalar("int16"), {"type": "integer", "minimum": -32768, "maximum": 32767}),
        (scalar("uint32"), {"type": "integer", "minimum": 0, "maximum": 4294967295}),
        (scalar("int64"), {"type": "integer", "minimum": -(2**63), "maximum": 2**63 - 1}),
        (scalar("uint64"), {"type": "integer", "minimum": 0, "maximum": 2**64 - 1}),
        (scalar("char"), {"type": "integer", "minimum": 0, "maximum": 255}),
        (scalar("float"), {"type": "number", "minimum": -FLOAT32_MAX, "maximum": FLOAT32_MAX}),
        (scalar("double"), {"type": "number"}),
        (scalar("string"), {"type": "string"}),
        (scalar("string", string_bound=10), {"type": "string", "maxLength": 10}),
        (scalar("wstring"), {"type": "string"}),
        (
            Field("v", "int32", "sequence<int32>", "sequence"),
            {"type": "array", "items": {"type": "integer", "minimum": -(2**31), "maximum": 2**31 - 1}},
        ),
        (
            Field("v", "double", "sequence<double, 5>", "sequence", 5),
            {"type": "array", "items": {"type": "number"}, "maxItems": 5},
        ),
        (
            Field("v", "double", "double[9]", "array", 9),
            {"type": "array", "items": {"type": "number"}, "maxItems": 9, "minItems": 9},
        ),
        (
            Field("v", "string", "sequence<string<4>, 2>", "sequence", 2, 4),
            {"type": "array", "items": {"type": "string", "maxLength": 4}, "maxItems": 2},
        ),
        (
            Field("data", "uint8", "sequence<uint8>", "sequence"),
            {"type": "string", "contentEncoding": "base64", "description": "bytes, base64"},
        ),
        (
            Field("data", "uint8", "sequence<uint8, 10>", "sequence", 10),
            {
                "type": "string",
                "contentEncoding": "base64",
                "maxLength": 16,
                "description": "at most 10 bytes, base64",
            },
        ),
        (
            Field("uuid", "uint8", "uint8[16]", "array", 16),
            {
                "type": "string",
                "contentEncoding": "base64",
                "maxLength": 24,
                "minLength": 24,
                "description": "exactly 16 bytes, base64",
            },
        ),
    ],
)
def test_each_field_kind(field: Field, schema: dict[str, Any]) -> None:
    assert field_schema(field) == schema


def test_wchar_is_not_supported() -> None:
    with pytest.raises(SchemaProblem, match="not supported"):
        field_schema(scalar("wchar"))


def test_nested_messages_are_closed_objects_with_time_and_constants_described() -> None:
    pose = describe("geometry_msgs/msg/PoseStamped").input
    schema = message_schema(pose)
    assert schema["type"] == "object" and schema["additionalProperties"] is False and "required" not in schema
    header = schema["properties"]["header"]
    assert header["additionalProperties"] is False
    stamp = header["properties"]["stamp"]
    assert stamp["properties"] == {
        "sec": {"type": "integer", "minimum": -(2**31), "maximum": 2**31 - 1},
        "nanosec": {"type": "integer", "minimum": 0, "maximum": 2**32 - 1},
    }
    assert "sec" in stamp["description"] and "nanosec" in stamp["description"]
    assert schema["properties"]["pose"]["properties"]["orientation"]["properties"]["w"] == {"type": "number"}
    status = message_schema(describe("sensor_msgs/msg/NavSatFix").input)["properties"]["status"]
    assert "STATUS_FIX=0" in status["description"] and "SERVICE_GPS=1" in status["description"]


def test_sequences_of_messages() -> None:
    response = describe("action_msgs/srv/CancelGoal").part("response")
    goals = message_schema(response)["properties"]["goals_canceling"]
    assert goals["type"] == "array"
    assert goals["items"]["properties"]["goal_id"]["properties"]["uuid"]["minLength"] == 24


def arg(**settings: Any) -> ArgumentConfig:
    return ArgumentConfig("a", **settings)


PARENT = Message(
    "p/msg/T", constants=(Constant("MODE_FAST", 2), Constant("NAME", "x"), Constant("GAIN", 0.5))
)


def test_the_file_tightens_bounds_and_the_parent_constants_are_listed() -> None:
    schema = argument_schema(
        scalar("uint8"), arg(field="x", minimum=1, maximum=3.0, description="mode"), PARENT
    )
    assert schema == {
        "type": "integer",
        "minimum": 1,
        "maximum": 3,
        "description": "mode; constants: MODE_FAST=2",
    }
    assert isinstance(schema["maximum"], int)
    speed = argument_schema(scalar("double"), arg(field="x", minimum=0.1, maximum=1.0), EMPTY)
    assert speed == {"type": "number", "minimum": 0.1, "maximum": 1.0}
    name = argument_schema(scalar("string", string_bound=20), arg(field="x", max_length=8), PARENT)
    assert name == {"type": "string", "maxLength": 8, "description": "constants: NAME='x'"}
    items = argument_schema(
        Field("v", "double", "sequence<double>", "sequence"), arg(field="v", max_items=3), PARENT
    )
    assert items == {"type": "array", "items": {"type": "number"}, "maxItems": 3}
    data = argument_schema(
        Field("d", "uint8", "sequence<uint8>", "sequence"), arg(field="d", max_items=6), EMPTY
    )
    assert data["maxLength"] == 8 and data["description"] == "at most 6 bytes, base64"


@pytest.mark.parametrize(
    ("field", "argument", "problem"),
    [
        (scalar("uint8"), arg(field="x", maximum=256), r"maximum: 256 is outside the uint8 range \[0, 255\]"),
        (scalar("int8"), arg(field="x", minimum=-129), "minimum: -129 is outside"),
        (scalar("float"), arg(field="x", maximum=1e39), "maximum: 1e\\+39 is outside"),
        (scalar("uint8"), arg(field="x", minimum=0.5), "not whole"),
        (scalar("string"), arg(field="x", maximum=3), "not a number"),
        (scalar("boolean"), arg(field="x", minimum=0), "not a number"),
        (scalar("double"), arg(field="x", max_length=3), "not a string"),
        (scalar("string", string_bound=5), arg(field="x", max_length=6), "beyond the bound"),
        (scalar("string"), arg(field="x", max_items=6), "not an array"),
        (
            Field("v", "double", "sequence<double, 4>", "sequence", 4),
            arg(field="v", max_items=5),
            "beyond the bound",
        ),
        (Field("v", "double", "double[4]", "array", 4), arg(field="v", max_items=3), "always has 4"),
        (Field("v", "double", "sequence<double>", "sequence"), arg(field="v", minimum=1), "not a number"),
    ],
)
def test_bounds_outside_the_type_are_refused(field: Field, argument: ArgumentConfig, problem: str) -> None:
    with pytest.raises(SchemaProblem, match=problem):
        argument_schema(field, argument, EMPTY)


def test_choices_confirm_and_the_empty_object() -> None:
    assert choices_schema(["kitchen", "door"], "where") == {
        "type": "string",
        "enum": ["kitchen", "door"],
        "description": "where",
    }
    empty = parameters_schema({}, [], confirm=False)
    assert empty == {"type": "object", "properties": {}, "required": [], "additionalProperties": False}
    confirmed = parameters_schema({"a": {"type": "boolean"}}, ["a"], confirm=True)
    assert confirmed["required"] == ["a", "confirmed"]
    assert confirmed["properties"]["confirmed"]["type"] == "boolean"
