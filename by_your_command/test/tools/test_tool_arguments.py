"""The model's arguments: parsing, the validator's refusals (each saying which argument and why),
normalisation, and how the request is built (fixed fields always win)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from by_your_command.tools.arguments import build_message, check_schema, parse_arguments, validate
from by_your_command.tools.errors import ToolArgumentError

pytestmark = pytest.mark.unit

SCHEMA: dict[str, Any] = {
    "type": "object",
    "properties": {
        "place": {"type": "string", "enum": ["kitchen", "front door"]},
        "speed": {"type": "number", "minimum": 0.1, "maximum": 1.0},
        "count": {"type": "integer", "minimum": 0, "maximum": 255},
        "loud": {"type": "boolean"},
        "name": {"type": "string", "maxLength": 5},
        "data": {"type": "string", "contentEncoding": "base64", "maxLength": 8},
        "joints": {"type": "array", "items": {"type": "number"}, "maxItems": 2},
        "k": {"type": "array", "items": {"type": "integer"}, "minItems": 2, "maxItems": 2},
        "pose": {
            "type": "object",
            "properties": {
                "position": {
                    "type": "object",
                    "properties": {"x": {"type": "number"}},
                    "additionalProperties": False,
                }
            },
            "additionalProperties": False,
        },
    },
    "required": ["place"],
    "additionalProperties": False,
}


def check(arguments: dict[str, Any]) -> Any:
    return validate(SCHEMA, {"place": "kitchen", **arguments})


def test_valid_arguments_are_returned_normalised() -> None:
    value = check(
        {
            "speed": 1,
            "count": 3.0,
            "loud": False,
            "name": "abc",
            "data": "AAEC",
            "joints": [1, 2.5],
            "k": [1, 2],
        }
    )
    assert value["speed"] == 1.0 and isinstance(value["speed"], float)
    assert value["count"] == 3 and isinstance(value["count"], int)
    assert value["joints"] == [1.0, 2.5] and all(isinstance(j, float) for j in value["joints"])
    assert check({"pose": {"position": {"x": -2}}})["pose"] == {"position": {"x": -2.0}}
    assert check({"pose": {}})["pose"] == {}  # nested fields keep their ROS defaults


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({"place": "garage"}, "argument 'place' must be one of: kitchen, front door (not \"garage\")"),
        ({"place": 3}, "argument 'place' must be one of the names, not 3"),
        ({"speed": "fast"}, "argument 'speed' must be a number, not \"fast\""),
        ({"speed": True}, "argument 'speed' must be a number, not true"),
        ({"speed": None}, "argument 'speed' must be a number, not null"),
        ({"speed": 2}, "argument 'speed' must be at most 1, not 2"),
        ({"speed": 0.01}, "argument 'speed' must be at least 0.1, not 0.01"),
        ({"speed": float("inf")}, "argument 'speed' must be a finite number"),
        ({"speed": float("nan")}, "argument 'speed' must be a finite number"),
        ({"speed": 10**400}, "argument 'speed' is far too large"),
        ({"count": True}, "argument 'count' must be a whole number, not true"),
        ({"count": 1.5}, "argument 'count' must be a whole number, not 1.5"),
        ({"count": 256}, "argument 'count' must be at most 255, not 256"),
        ({"count": -1}, "argument 'count' must be at least 0, not -1"),
        ({"count": "3"}, "argument 'count' must be a whole number, not \"3\""),
        ({"loud": 1}, "argument 'loud' must be true or false, not 1"),
        ({"loud": "true"}, "argument 'loud' must be true or false, not \"true\""),
        ({"name": "abcdef"}, "argument 'name' is too long: at most 5 characters"),
        ({"name": 5}, "argument 'name' must be text, not 5"),
        ({"data": "!!!!"}, "argument 'data' must be base64 text"),
        ({"data": "AAECAAECAAEC"}, "argument 'data' is too long: at most 8 characters"),
        ({"joints": [1, 2, 3]}, "argument 'joints' has 3 items, at most 2 are allowed"),
        ({"joints": 1}, "argument 'joints' must be a list, not 1"),
        ({"joints": [1, "a"]}, "argument 'joints[1]' must be a number, not \"a\""),
        ({"k": [1]}, "argument 'k' has 1 items, it needs 2"),
        ({"pose": []}, "argument 'pose' must be an object, not a list of 0"),
        ({"pose": {"position": {"y": 1}}}, "argument 'pose.position' has no field 'y' (expected: x)"),
        ({"pose": {"position": {"x": "1"}}}, "argument 'pose.position.x' must be a number, not \"1\""),
        (
            {"colour": "red"},
            "unknown argument 'colour' (expected: count, data, joints, k, loud, name, place, pose, speed)",
        ),
    ],
)
def test_wrong_arguments_are_refused_naming_the_argument(arguments: dict[str, Any], message: str) -> None:
    with pytest.raises(ToolArgumentError) as caught:
        check(arguments)
    assert str(caught.value) == message


def test_missing_and_deep_arguments() -> None:
    with pytest.raises(ToolArgumentError, match="^missing argument 'place'$"):
        validate(SCHEMA, {})
    deep: Any = 1.0
    for _ in range(40):
        deep = {"x": deep}
    with pytest.raises(ToolArgumentError, match="nested more than 32 deep"):
        validate(SCHEMA, {"place": "kitchen", "pose": deep})
    with pytest.raises(ToolArgumentError, match="the arguments must be an object"):
        validate(SCHEMA, ["kitchen"])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("not json", "the arguments are not valid JSON"),
        ('{"speed": NaN}', "the arguments are not valid JSON"),
        ('{"speed": Infinity}', "the arguments are not valid JSON"),
        ("[1]", "the arguments must be a JSON object, not a list of 1"),
        ('"kitchen"', "the arguments must be a JSON object"),
        ("[" * 100_000 + "]" * 100_000, "nested too deeply|not valid JSON"),
        ('{"a": "' + "x" * 300_000 + '"}', "the arguments are too long"),
    ],
)
def test_unparsable_arguments(text: str, message: str) -> None:
    with pytest.raises(ToolArgumentError, match=message):
        parse_arguments(text)


def test_empty_arguments_mean_none() -> None:
    assert parse_arguments("") == {} and parse_arguments("  ") == {} and parse_arguments("{}") == {}
    assert parse_arguments('{"a": 1}') == {"a": 1}


def test_a_huge_number_in_json_is_not_finite() -> None:
    with pytest.raises(ToolArgumentError, match="finite"):
        validate(SCHEMA, parse_arguments(json.dumps({"place": "kitchen"})[:-1] + ', "speed": 1e400}'))


def test_the_builder_merges_fixed_choices_and_model_values_without_overriding_fixed() -> None:
    fixed = {"pose": {"header": {"frame_id": "map"}}}
    kitchen = {"pose": {"pose": {"position": {"x": 3.0}, "orientation": {"w": 1.0}}}}
    message = build_message(fixed, [("", kitchen), ("max_speed", 0.5), ("behavior", {"name": "fast"})])
    assert message == {
        "pose": {"header": {"frame_id": "map"}, "pose": {"position": {"x": 3.0}, "orientation": {"w": 1.0}}},
        "max_speed": 0.5,
        "behavior": {"name": "fast"},
    }
    assert fixed == {"pose": {"header": {"frame_id": "map"}}}  # not mutated
    kitchen["pose"]["pose"]["position"]["x"] = 99.0
    assert message["pose"]["pose"]["position"]["x"] == 3.0  # copied, not shared
    # second line of defence: a value at a fixed field is ignored (such configs are refused at load)
    attempt = build_message(
        {"pose": {"header": {"frame_id": "map"}}}, [("pose.header", {"frame_id": "odom"})]
    )
    assert attempt == {"pose": {"header": {"frame_id": "map"}}}
    assert build_message({"a": 1}, [("a", 2)]) == {"a": 1}


def test_check_schema_accepts_generated_schemas_and_refuses_others() -> None:
    check_schema(SCHEMA)
    for bad in (
        {"type": "object", "properties": {}, "additionalProperties": True},
        {
            "type": "object",
            "properties": {"a": {"type": "string", "pattern": ".*"}},
            "additionalProperties": False,
        },
        {"type": "object", "properties": {"a": {"type": "weird"}}, "additionalProperties": False},
        {"type": "object", "properties": {}, "required": ["a"], "additionalProperties": False},
        {
            "type": "object",
            "properties": {"a": {"type": "integer", "maximum": "9"}},
            "additionalProperties": False,
        },
        {
            "type": "object",
            "properties": {"a": {"type": "string", "enum": []}},
            "additionalProperties": False,
        },
        {
            "type": "object",
            "properties": {"a": {"type": "string", "enum": ["x", "x"]}},
            "additionalProperties": False,
        },
        {
            "type": "object",
            "properties": {"a": {"type": "array", "maxItems": -1, "items": {"type": "number"}}},
            "additionalProperties": False,
        },
        {"type": "object", "properties": {"a": {"type": "array"}}, "additionalProperties": False},
        {"type": "string"},
        "object",
    ):
        with pytest.raises(ValueError):
            check_schema(bad)
