"""The catalog: built from tools.yaml and the installed interfaces, sent as JSON and read back
strictly (it is untrusted on the agents' side), and what a tool does with the model's arguments."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from typing import Any

import pytest
from byc_testing import REPO_ROOT

from by_your_command.ros.interfaces import describe
from by_your_command.tools.catalog import (
    Catalog,
    CatalogError,
    RobotTool,
    ToolArgumentError,
    ToolsConfigError,
    build_catalog,
)
from by_your_command.tools.config import load_tools_config, parse_tools_config
from by_your_command.tools.interface_types import Interface

pytestmark = pytest.mark.unit

DEMO = REPO_ROOT / "by_your_command" / "config" / "tools_demo.yaml"
NAVIGATE = "by_your_command_msgs/action/NavigateToPose"


@pytest.fixture(scope="module")
def demo() -> Catalog:
    return build_catalog(load_tools_config(DEMO), describe)


def catalog_of(tools: dict[str, Any], describe_: Callable[[str], Interface] = describe) -> Catalog:
    return build_catalog(parse_tools_config({"tools": tools}), describe_)


def tool_of(tools: dict[str, Any]) -> RobotTool:
    (tool,) = catalog_of(tools).tools
    return tool


def test_the_demo_catalog(demo: Catalog) -> None:
    assert [(t.name, t.kind, t.ros_name, t.type) for t in demo.tools] == [
        ("go_to", "action", "navigate_to_pose", NAVIGATE),
        ("dock", "service", "dock", "by_your_command_msgs/srv/Trigger"),
        ("battery", "service", "battery_status", "by_your_command_msgs/srv/Trigger"),
        ("look", "command", "", ""),
    ]
    go_to = demo.get("go_to")
    assert go_to is not None and demo.get("nope") is None
    assert go_to.parameters == {
        "type": "object",
        "properties": {
            "place": {
                "type": "string",
                "enum": ["kitchen", "living room", "charging dock", "front door"],
                "description": "where to go",
            }
        },
        "required": ["place"],
        "additionalProperties": False,
    }
    assert go_to.feedback is not None and go_to.feedback.every_s == 3.0
    assert go_to.feedback.fields == ("distance_remaining",)
    battery = demo.get("battery")
    assert battery is not None and battery.rules.while_asleep and battery.parameters["properties"] == {}


def test_building_a_goal_merges_fixed_fields_and_the_choice(demo: Catalog) -> None:
    go_to = demo.get("go_to")
    assert go_to is not None
    assert go_to.build('{"place": "front door"}') == {
        "pose": {
            "header": {"frame_id": "map"},
            "pose": {"position": {"x": 4.5, "y": -2.0}, "orientation": {"w": 1.0}},
        }
    }
    with pytest.raises(ToolArgumentError, match="argument 'place' must be one of: kitchen, living room"):
        go_to.build('{"place": "garage"}')
    with pytest.raises(ToolArgumentError, match="missing argument 'place'"):
        go_to.build("{}")
    with pytest.raises(ToolArgumentError, match="unknown argument 'pose'"):
        go_to.build('{"place": "kitchen", "pose": {}}')
    dock = demo.get("dock")
    assert dock is not None and dock.build("") == {} and dock.build("{}") == {}


def test_the_built_goal_converts_to_the_ros_goal(demo: Catalog) -> None:
    from by_your_command.ros.convert import from_dict, part_class

    go_to = demo.get("go_to")
    assert go_to is not None
    goal = from_dict(part_class(go_to.type, "goal"), go_to.build('{"place": "kitchen"}'))
    assert (goal.pose.header.frame_id, goal.pose.pose.position.x, goal.pose.pose.orientation.w) == (
        "map",
        3.0,
        1.0,
    )


def test_a_command_tool(demo: Catalog) -> None:
    look = demo.get("look")
    assert look is not None
    assert look.command_text('{"direction": "right"}') == "pan@right"
    with pytest.raises(ToolArgumentError, match="argument 'direction' must be one of: left, right"):
        look.command_text('{"direction": "up"}')
    with pytest.raises(ValueError, match="command tool"):
        look.build('{"direction": "right"}')
    go_to = demo.get("go_to")
    assert go_to is not None
    with pytest.raises(ValueError, match="action tool"):
        go_to.command_text('{"place": "kitchen"}')
    mapped = tool_of(
        {"arm": {"command": "arm@{pose}", "arguments": {"pose": {"choices": {"up high": "bumper"}}}}}
    )
    assert mapped.command_text('{"pose": "up high"}') == "arm@bumper"
    bare = tool_of({"salute": {"command": "tenhut"}})
    assert bare.command_text("") == "tenhut" and bare.parameters["properties"] == {}


def test_spoken_forms(demo: Catalog) -> None:
    forms = {tool.name: tool.spoken_forms() for tool in demo.tools}
    assert forms["go_to"][:2] == [
        ("go to the kitchen", {"place": "kitchen"}),
        ("go to the living room", {"place": "living room"}),
    ]
    assert len(forms["go_to"]) == 12 and ("go to front door", {"place": "front door"}) in forms["go_to"]
    assert ("drive to the charging dock", {"place": "charging dock"}) in forms["go_to"]
    assert forms["dock"] == [("dock", {}), ("go dock", {})]
    assert forms["battery"] == [("what's your battery", {}), ("battery status", {})]
    assert forms["look"] == [("look left", {"direction": "left"}), ("look right", {"direction": "right"})]
    for tool in demo.tools:  # every spoken form is a valid call
        for _, arguments in tool.spoken_forms():
            if tool.kind == "command":
                tool.command_text(json.dumps(arguments))
            else:
                tool.build(json.dumps(arguments))


def test_two_argument_forms() -> None:
    tool = tool_of(
        {
            "point": {
                "command": "{part}@{side}",
                "arguments": {"part": {"choices": ["pan", "tilt"]}, "side": {"choices": ["a", "b"]}},
                "spoken": ["{part} to {side}"],
            }
        }
    )
    assert [phrase for phrase, _ in tool.spoken_forms()] == ["pan to a", "pan to b", "tilt to a", "tilt to b"]
    assert tool.spoken_forms()[1][1] == {"part": "pan", "side": "b"}


def test_feedback_summary(demo: Catalog) -> None:
    go_to = demo.get("go_to")
    assert go_to is not None
    assert (
        go_to.feedback_summary({"distance_remaining": 3.14159, "number_of_recoveries": 2})
        == "distance_remaining 3.14"
    )
    assert go_to.feedback_summary({"number_of_recoveries": 2}) == ""
    assert go_to.feedback_summary("junk") == ""  # type: ignore[arg-type]
    every = tool_of({"nav": {"action": "/n", "type": NAVIGATE, "feedback": {"every_s": 1}}})
    assert every.feedback is not None and every.feedback.fields == (
        "current_pose",
        "navigation_time",
        "estimated_time_remaining",
        "number_of_recoveries",
        "distance_remaining",
    )
    text = every.feedback_summary(
        {
            "navigation_time": {"sec": 12, "nanosec": 500_000_000},
            "estimated_time_remaining": {"sec": 3, "nanosec": 0},
            "number_of_recoveries": 1,
            "distance_remaining": 2.0,
            "current_pose": {"header": {"frame_id": "x" * 500}},
        }
    )
    assert (
        "navigation_time 12.5 s, estimated_time_remaining 3 s, number_of_recoveries 1, distance_remaining 2"
        in text
    )
    assert len(text) <= 300
    nested = tool_of(
        {"nav": {"action": "/n", "type": NAVIGATE, "feedback": {"fields": ["current_pose.pose.position.x"]}}}
    )
    assert (
        nested.feedback_summary({"current_pose": {"pose": {"position": {"x": -0.004}}}})
        == "current_pose.pose.position.x 0"
    )
    quiet = tool_of({"nav": {"action": "/n", "type": NAVIGATE}})
    assert quiet.feedback is None and quiet.feedback_summary({"distance_remaining": 1.0}) == ""


def test_arguments_absent_means_every_field_not_fixed() -> None:
    nav = tool_of({"nav": {"action": "/n", "type": NAVIGATE, "fixed": {"behavior_tree": "bt.xml"}}})
    assert list(nav.parameters["properties"]) == ["pose"] and nav.parameters["required"] == []
    goal = nav.build('{"pose": {"pose": {"position": {"x": 1}}}}')
    assert goal == {"behavior_tree": "bt.xml", "pose": {"pose": {"position": {"x": 1.0}}}}
    with pytest.raises(ToolArgumentError, match="argument 'pose.pose.position' has no field 'q'"):
        nav.build('{"pose": {"pose": {"position": {"q": 1}}}}')
    say = tool_of({"say": {"topic": "/say", "type": "std_msgs/String"}})
    assert say.build('{"data": "hi"}') == {"data": "hi"} and say.type == "std_msgs/msg/String"


def test_field_arguments_list_choices_and_confirm() -> None:
    tool = tool_of(
        {
            "cam": {
                "service": "/cancel",
                "type": "action_msgs/srv/CancelGoal",
                "fixed": {"goal_info.stamp.sec": 5},
                "arguments": {
                    "nanos": {"field": "goal_info.stamp.nanosec", "maximum": 1000, "description": "ns"},
                    "id": {
                        "field": "goal_info.goal_id.uuid",
                        "choices": {"zero": "AAAAAAAAAAAAAAAAAAAAAA=="},
                    },
                },
                "confirm": True,
            }
        }
    )
    assert tool.parameters["required"] == ["nanos", "id", "confirmed"]
    assert tool.parameters["properties"]["nanos"] == {
        "type": "integer",
        "minimum": 0,
        "maximum": 1000,
        "description": "ns",
    }
    built = tool.build('{"nanos": 7.0, "id": "zero", "confirmed": true}')
    assert built == {
        "goal_info": {"stamp": {"sec": 5, "nanosec": 7}, "goal_id": {"uuid": "AAAAAAAAAAAAAAAAAAAAAA=="}}
    }
    assert isinstance(built["goal_info"]["stamp"]["nanosec"], int)
    with pytest.raises(ToolArgumentError, match="'confirmed' must be true"):
        tool.build('{"nanos": 7, "id": "zero", "confirmed": false}')
    with pytest.raises(ToolArgumentError, match="missing argument 'confirmed'"):
        tool.build('{"nanos": 7, "id": "zero"}')
    with pytest.raises(ToolArgumentError, match="argument 'nanos' must be at most 1000"):
        tool.build('{"nanos": 1001, "id": "zero", "confirmed": true}')


def go_to_with(**changes: Any) -> dict[str, Any]:
    tool: dict[str, Any] = {
        "action": "/navigate_to_pose",
        "type": NAVIGATE,
        "fixed": {"pose.header.frame_id": "map"},
        "arguments": {"place": {"choices": {"kitchen": {"pose.pose.position.x": 3.0}}}},
    }
    for key, value in changes.items():
        tool[key] = value
    return {"go_to": tool}


@pytest.mark.parametrize(
    ("changes", "key", "problem"),
    [
        ({"type": "by_your_command_msgs/action/Nope"}, "type", "not installed"),
        ({"type": "no_such_pkg/action/Nope"}, "type", "not installed"),
        ({"fixed": {"pose.header.frame": "map"}}, "fixed", "field 'pose.header' has no field 'frame'"),
        ({"fixed": {"pose.header.frame_id": 3}}, "fixed", "field 'pose.header.frame_id' must be text, not 3"),
        ({"fixed": {"pose.pose.position.x": "far"}}, "fixed", "must be a number"),
        ({"arguments": {"place": {"field": "pose.pose.place"}}}, "arguments.place.field", "has no field"),
        ({"arguments": {"place": {"field": "pose.header.frame_id"}}}, "arguments.place", "which is fixed"),
        ({"arguments": {"place": {"field": "pose.header"}}}, "arguments.place", "which is fixed"),
        (
            {"arguments": {"place": {"choices": {"home": {"pose.header.frame_id": "odom"}}}}},
            "arguments.place",
            "which is fixed",
        ),
        (
            {
                "arguments": {
                    "a": {"choices": {"x": {"pose.pose.position.x": 1.0}}},
                    "b": {"field": "pose.pose"},
                }
            },
            "arguments.b",
            "like argument 'a'",
        ),
        (
            {"arguments": {"place": {"choices": {"kitchen": {"pose.pose.position.x": "three"}}}}},
            "arguments.place.choices.kitchen",
            "field 'pose.pose.position.x' must be a number",
        ),
        (
            {"arguments": {"bt": {"field": "behavior_tree", "choices": {"fast": 3}}}},
            "arguments.bt.choices.fast",
            "must be text",
        ),
        ({"arguments": {"bt": {"field": "behavior_tree", "maximum": 3}}}, "arguments.bt", "not a number"),
        ({"feedback": {"fields": ["speed"]}}, "feedback.fields", "has no field 'speed'"),
    ],
)
def test_a_file_that_does_not_fit_the_interface_is_refused(
    changes: dict[str, Any], key: str, problem: str
) -> None:
    with pytest.raises(ToolsConfigError) as caught:
        catalog_of(go_to_with(**changes))
    assert str(caught.value).startswith(f"tool 'go_to': {key}: ") and problem in str(caught.value), (
        caught.value
    )


def test_the_interface_kind_must_match_the_tool_kind() -> None:
    def as_message(name: str) -> Interface:
        return describe("std_msgs/msg/String")

    with pytest.raises(
        ToolsConfigError, match="tool 'go_to': type: std_msgs/msg/String is not an action type"
    ):
        catalog_of(go_to_with(), as_message)


def test_the_catalog_round_trips(demo: Catalog) -> None:
    text = demo.to_json()
    again = Catalog.from_json(text)
    assert again == demo and again.to_json() == text
    assert Catalog.from_json(Catalog().to_json()) == Catalog()
    confirm = catalog_of({"c": {"service": "/c", "type": "action_msgs/srv/CancelGoal", "confirm": True}})
    assert Catalog.from_json(confirm.to_json()) == confirm


def hostile(change: Callable[[dict[str, Any]], Any], catalog: Catalog) -> str:
    data = json.loads(catalog.to_json())
    change(data)
    return json.dumps(data)


def _go_to(data: dict[str, Any]) -> dict[str, Any]:
    tool: dict[str, Any] = data["tools"][0]
    return tool


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def change(data: dict[str, Any]) -> None:
        node: Any = _go_to(data)
        *parents, last = path.split("/")
        for part in parents:
            node = node[int(part)] if isinstance(node, list) else node[part]
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value

    return change


def _deep_schema() -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "boolean"}
    for _ in range(40):
        schema = {"type": "object", "properties": {"a": schema}, "additionalProperties": False}
    return schema


HOSTILE_CHANGES: list[tuple[str, Callable[[dict[str, Any]], Any]]] = [
    ("version 2", lambda d: d.update(version=2)),
    ("version true", lambda d: d.update(version=True)),
    ("no version", lambda d: d.pop("version")),
    ("extra top-level key", lambda d: d.update(extra=1)),
    ("tools not a list", lambda d: d.update(tools={})),
    ("tool not an object", lambda d: d["tools"].append("go_to")),
    ("65 tools", lambda d: d.update(tools=[dict(d["tools"][3], name=f"t{i}") for i in range(65)])),
    ("duplicate name", lambda d: d["tools"].append(d["tools"][0])),
    ("names differ in case", lambda d: d["tools"].append(dict(d["tools"][0], name="GO_TO"))),
    ("missing key", lambda d: _go_to(d).pop("rules")),
    ("extra key", lambda d: _go_to(d).update(colour="red")),
    ("reserved name", _set("name", "robot_command")),
    ("bad name", _set("name", "go to")),
    ("long name", _set("name", "g" * 65)),
    ("name not text", _set("name", 3)),
    ("unknown kind", _set("kind", "rocket")),
    ("bad ros name", _set("ros_name", "navigate to")),
    ("empty ros name", _set("ros_name", "")),
    ("service type for an action", _set("type", "by_your_command_msgs/srv/Trigger")),
    ("short type", _set("type", "by_your_command_msgs/NavigateToPose")),
    ("command on an action", _set("command", "pan@left")),
    ("long description", _set("description", "x" * 1001)),
    ("parameters not an object", _set("parameters", [])),
    ("schema keyword unknown", _set("parameters/properties/place/pattern", ".*")),
    ("schema open object", _set("parameters/additionalProperties", True)),
    ("schema too deep", _set("parameters/properties/place", _deep_schema())),
    ("enum differs from choices", _set("parameters/properties/place/enum", ["kitchen"])),
    ("property without argument", _set("parameters/properties/extra", {"type": "number"})),
    ("argument without property", lambda d: _go_to(d)["arguments"].append({"name": "speed", "field": "x"})),
    ("argument extra key", _set("arguments/0/colour", 1)),
    ("argument without field or choices", lambda d: _go_to(d)["arguments"][0].pop("choices")),
    ("choices not an object", _set("arguments/0/choices", ["kitchen"])),
    (
        "choice overrides fixed",
        _set("arguments/0/choices/kitchen", {"pose": {"header": {"frame_id": "odom"}}}),
    ),
    ("choice not an object at the top", _set("arguments/0/choices/kitchen", 3)),
    ("rules negative", _set("rules/min_interval_s", -1)),
    ("rules zero timeout", _set("rules/timeout_s", 0)),
    ("rules huge", _set("rules/max_duration_s", 1e400)),
    ("rules bool", _set("rules/timeout_s", True)),
    ("rules string", _set("rules/confirm", "no")),
    ("rules missing key", lambda d: _go_to(d)["rules"].pop("confirm")),
    ("confirm without confirmed", _set("rules/confirm", True)),
    ("feedback zero", _set("feedback/every_s", 0)),
    ("feedback bad field", _set("feedback/fields", ["a b"])),
    ("feedback extra key", _set("feedback/colour", 1)),
    ("spoken placeholder unknown", _set("spoken/0", "go to {where}")),
    ("spoken misses the argument", _set("spoken/0", "go somewhere")),
    ("spoken not text", _set("spoken/0", 3)),
    ("spoken too many", _set("spoken", ["go to {place}"] * 33)),
    ("fixed nested too deep", _set("fixed", json.loads('{"a":' * 40 + "1" + "}" * 40))),
    ("command tool with type", lambda d: d["tools"][3].update(type="std_msgs/msg/String")),
    (
        "command value with a comma",
        lambda d: d["tools"][3]["arguments"][0]["choices"].update(left="left, tenhut"),
    ),
    ("command template stray brace", lambda d: d["tools"][3].update(command="pan@{direction")),
    ("command template too long", lambda d: d["tools"][3].update(command="x" * 190 + "{direction}")),
    ("service with feedback", lambda d: d["tools"][1].update(feedback={"every_s": 1, "fields": []})),
]


@pytest.mark.parametrize(("what", "change"), HOSTILE_CHANGES, ids=[what for what, _ in HOSTILE_CHANGES])
def test_from_json_refuses_anything_odd(
    demo: Catalog, what: str, change: Callable[[dict[str, Any]], Any]
) -> None:
    text = hostile(change, demo)
    with pytest.raises(CatalogError):
        Catalog.from_json(text)


@pytest.mark.parametrize(
    "text",
    [
        "",
        "not json",
        "[]",
        "null",
        '{"version": 1, "tools": [], "version": 1}',
        '{"version": NaN, "tools": []}',
        '{"version": 1, "tools": [' * 5000,
        "[" * 100_000 + "]" * 100_000,
        '{"version": 1, "tools": []}' + " " * 2_000_001,
    ],
)
def test_from_json_refuses_malformed_text(text: str) -> None:
    with pytest.raises(CatalogError):
        Catalog.from_json(text)


def test_from_json_refuses_a_non_finite_number_written_as_a_huge_one(demo: Catalog) -> None:
    text = demo.to_json().replace('"every_s":3.0', '"every_s":1e400')
    assert "1e400" in text
    with pytest.raises(CatalogError, match="every_s"):
        Catalog.from_json(text)


def test_a_catalog_built_by_hand_is_checked_like_a_received_one(demo: Catalog) -> None:
    tool = copy.deepcopy(demo.tools[0])
    assert Catalog.from_json(Catalog((tool,)).to_json()).tools == (tool,)


def test_phrases_made_from_a_name_are_dropped_when_the_interface_leaves_fields_to_fill() -> None:
    config = parse_tools_config(
        {
            "tools": {
                "dock": {"service": "dock", "type": "by_your_command_msgs/srv/Trigger"},  # nothing to fill
                "say": {"topic": "speech", "type": "std_msgs/msg/String"},  # `data` left to the model
            }
        }
    )
    catalog = build_catalog(config, describe)
    dock, say = catalog.get("dock"), catalog.get("say")
    assert dock is not None and dock.spoken_forms() == [("dock", {})]
    assert say is not None and say.spoken_forms() == []  # never "say" with an empty message
