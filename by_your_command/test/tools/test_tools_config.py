"""tools.yaml parsing: what is accepted, and every malformed or absurd value refused with the tool
and the key named."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
from byc_testing import REPO_ROOT

from by_your_command.tools.config import (
    FeedbackRule,
    ToolRules,
    ToolsConfigError,
    load_tools_config,
    parse_tools_config,
)

pytestmark = pytest.mark.unit

CONFIG_DIR = REPO_ROOT / "by_your_command" / "config"
GO_TO: dict[str, Any] = {
    "description": "Drive to a named place.",
    "action": "/navigate_to_pose",
    "type": "by_your_command_msgs/action/NavigateToPose",
    "fixed": {"pose.header.frame_id": "map"},
    "arguments": {
        "place": {
            "description": "where to go",
            "choices": {
                "kitchen": {"pose.pose.position.x": 3.0, "pose": {"pose": {"orientation.w": 1.0}}},
                "charging dock": {"pose.pose.position.x": 0.0},
            },
        }
    },
    "feedback": {"every_s": 3, "fields": ["distance_remaining"]},
    "min_interval_s": 2,
    "max_duration_s": 120,
    "timeout_s": 5,
    "spoken": ["go to the {place}"],
}
LOOK: dict[str, Any] = {
    "command": "pan@{direction}",
    "arguments": {"direction": {"choices": ["left", "right"]}},
}


def one_tool(**changes: Any) -> dict[str, Any]:
    """GO_TO with keys replaced (None removes the key)."""
    tool = copy.deepcopy(GO_TO)
    for key, value in changes.items():
        if value is None:
            tool.pop(key, None)
        else:
            tool[key] = value
    return {"tools": {"go_to": tool}}


def test_a_full_tool_is_parsed_with_nested_and_dotted_paths_merged() -> None:
    config = parse_tools_config({"tools": {"go_to": GO_TO, "look": LOOK}})
    go_to, look = config.tools
    assert (go_to.name, go_to.kind, go_to.ros_name, go_to.type) == (
        "go_to",
        "action",
        "/navigate_to_pose",
        "by_your_command_msgs/action/NavigateToPose",
    )
    assert go_to.fixed == {"pose": {"header": {"frame_id": "map"}}}
    assert go_to.arguments is not None
    assert go_to.arguments[0].choices == {
        "kitchen": {"pose": {"pose": {"position": {"x": 3.0}, "orientation": {"w": 1.0}}}},
        "charging dock": {"pose": {"pose": {"position": {"x": 0.0}}}},
    }
    assert go_to.rules == ToolRules(min_interval_s=2.0, max_duration_s=120.0, timeout_s=5.0)
    assert go_to.feedback == FeedbackRule(3.0, ("distance_remaining",))
    assert go_to.spoken == ("go to the {place}",)
    assert (look.kind, look.command, look.ros_name, look.type) == ("command", "pan@{direction}", "", "")
    assert look.arguments is not None and look.arguments[0].choices == {"left": "left", "right": "right"}


def test_defaults_and_short_type_names() -> None:
    config = parse_tools_config(
        {"tools": {"dock": {"service": "dock", "type": "by_your_command_msgs/Trigger"}}}
    )
    (dock,) = config.tools
    assert dock.type == "by_your_command_msgs/srv/Trigger"
    assert dock.rules == ToolRules(False, 0.0, 60.0, 10.0, False)
    assert dock.arguments is None and dock.feedback is None and dock.fixed == {}
    assert (
        dock.spoken == ("dock",) and dock.spoken_default
    )  # said by its name (the catalog checks the fields)


PLACE = {"field": "pose", "choices": {"kitchen": {"x": 1}}}
GO_TO_PHRASES = ("go to the {place}", "go to {place}")


@pytest.mark.parametrize(
    ("entry", "phrases"),
    [
        ({"action": "a", "type": "p/action/T", "arguments": {"place": PLACE}}, GO_TO_PHRASES),
        ({"action": "a", "type": "p/action/T", "arguments": {"speed": {"field": "speed"}}}, ()),
        ({"service": "s", "type": "p/srv/T", "confirm": True}, ()),
        ({"service": "s", "type": "p/srv/T", "spoken": []}, ()),
        ({"service": "s", "type": "p/srv/T", "spoken": ["drive there"]}, ("drive there",)),
    ],
)  # fmt: skip
def test_a_tool_without_phrases_is_said_by_its_name_when_that_is_safe(
    entry: dict[str, Any], phrases: tuple[str, ...]
) -> None:
    (tool,) = parse_tools_config({"tools": {"go_to": entry}}).tools
    assert tool.spoken == phrases


@pytest.mark.parametrize("data", [None, {"tools": {}}, {"tools": None}])
def test_no_tools_is_valid(data: Any) -> None:
    assert parse_tools_config(data).tools == ()


def test_the_shipped_default_declares_no_tools_and_the_demo_file_parses() -> None:
    assert load_tools_config(CONFIG_DIR / "tools.yaml").tools == ()
    demo = load_tools_config(CONFIG_DIR / "tools_demo.yaml")
    assert [tool.name for tool in demo.tools] == ["go_to", "dock", "battery", "look"]


def test_a_tool_declared_twice_in_yaml_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "tools.yaml"
    path.write_text("tools:\n  dock: {service: /a, type: p/srv/T}\n  dock: {service: /b, type: p/srv/T}\n")
    with pytest.raises(ToolsConfigError, match="duplicate key 'dock'"):
        load_tools_config(path)


@pytest.mark.parametrize(
    ("text", "problem"),
    [("tools: [", "not valid YAML"), ("- a\n- b\n", "one key, 'tools'"), ("tools: 3\n", "mapping")],
)
def test_unreadable_files_are_refused(tmp_path: Path, text: str, problem: str) -> None:
    path = tmp_path / "tools.yaml"
    path.write_text(text)
    with pytest.raises(ToolsConfigError, match=problem):
        load_tools_config(path)
    with pytest.raises(ToolsConfigError, match="cannot read"):
        load_tools_config(tmp_path / "missing.yaml")


NAN = float("nan")
INF = float("inf")


@pytest.mark.parametrize(
    ("changes", "key", "problem"),
    [
        ({"colour": "red"}, "colour", "unknown key"),
        ({"service": "/x"}, "action|service|topic|command", "exactly one"),
        ({"action": None}, "action|service|topic|command", "exactly one"),
        ({"action": "bad name!"}, "action", "invalid topic name"),
        ({"action": 3}, "action", "ROS name"),
        ({"type": None}, "type", "interface type is needed"),
        ({"type": "nav2_msgs/msg/NavigateToPose"}, "type", "invalid action type"),
        ({"type": "not a type"}, "type", "invalid action type"),
        ({"description": 3}, "description", "text"),
        ({"description": "x" * 1001}, "description", "at most 1000"),
        ({"while_asleep": "yes"}, "while_asleep", "true or false"),
        ({"confirm": 1}, "confirm", "true or false"),
        ({"min_interval_s": -1}, "min_interval_s", ">= 0"),
        ({"min_interval_s": NAN}, "min_interval_s", "number of seconds"),
        ({"max_duration_s": 0}, "max_duration_s", "> 0"),
        ({"max_duration_s": INF}, "max_duration_s", "number of seconds"),
        ({"max_duration_s": 1e9}, "max_duration_s", "<= 86400"),
        ({"timeout_s": -5}, "timeout_s", "> 0"),
        ({"timeout_s": True}, "timeout_s", "number of seconds"),
        ({"timeout_s": "10"}, "timeout_s", "number of seconds"),
        ({"timeout_s": 7200}, "timeout_s", "<= 3600"),
        ({"fixed": ["a"]}, "fixed", "mapping of field paths"),
        ({"fixed": {"pose..x": 1}}, "fixed", "not a field path"),
        ({"fixed": {"pose.x": NAN}}, "fixed", "not a finite number"),
        ({"fixed": {"pose.x": 1, "pose": {"x": 2}}}, "fixed", "set twice"),
        ({"fixed": {"pose": 1, "pose.x": 2}}, "fixed", "already set"),
        ({"arguments": []}, "arguments", "mapping of argument names"),
        ({"arguments": {"1place": {"field": "x"}}}, "arguments.1place", "invalid argument name"),
        ({"arguments": {"confirmed": {"field": "x"}}}, "arguments.confirmed", "reserved"),
        ({"arguments": {"place": "kitchen"}}, "arguments.place", "expected a mapping"),
        ({"arguments": {"place": {}}}, "arguments.place", "needs 'choices' or a 'field'"),
        ({"arguments": {"place": {"field": "x", "colour": 1}}}, "arguments.place.colour", "unknown key"),
        ({"arguments": {"place": {"field": "a..b"}}}, "arguments.place.field", "not a field path"),
        ({"arguments": {"place": {"field": 3}}}, "arguments.place.field", "dotted field path"),
        ({"arguments": {"s": {"field": "x", "minimum": NAN}}}, "arguments.s.minimum", "finite number"),
        ({"arguments": {"s": {"field": "x", "maximum": "1"}}}, "arguments.s.maximum", "finite number"),
        ({"arguments": {"s": {"field": "x", "minimum": 2, "maximum": 1}}}, "arguments.s.minimum", "above"),
        ({"arguments": {"s": {"field": "x", "max_length": -1}}}, "arguments.s.max_length", "whole number"),
        ({"arguments": {"s": {"field": "x", "max_items": 1.5}}}, "arguments.s.max_items", "whole number"),
        (
            {"arguments": {"s": {"field": "f", "choices": ["a"], "maximum": 1}}},
            "arguments.s.maximum",
            "not to choices",
        ),
        ({"arguments": {"s": {"choices": "a"}}}, "arguments.s.choices", "list of names or a mapping"),
        ({"arguments": {"s": {"choices": []}}}, "arguments.s.choices", "at least one"),
        ({"arguments": {"s": {"field": "f", "choices": ["a", "a"]}}}, "arguments.s.choices", "listed twice"),
        (
            {"arguments": {"s": {"field": "f", "choices": ["Kitchen", "kitchen"]}}},
            "arguments.s.choices",
            "listed twice",
        ),
        ({"arguments": {"s": {"choices": ["{a}"]}}}, "arguments.s.choices", "no braces"),
        ({"arguments": {"s": {"choices": [" a"]}}}, "arguments.s.choices", "surrounding spaces"),
        ({"arguments": {"s": {"choices": [3]}}}, "arguments.s.choices", "text of 1..64"),
        ({"arguments": {"s": {"choices": ["x" * 65]}}}, "arguments.s.choices", "text of 1..64"),
        (
            {"arguments": {"s": {"choices": [f"c{i}" for i in range(257)]}}},
            "arguments.s.choices",
            "at most 256",
        ),
        ({"arguments": {"s": {"choices": {"a": 3}}}}, "arguments.s.choices.a", "mapping of field paths"),
        ({"arguments": {"s": {"choices": {"a": {"x": INF}}}}}, "arguments.s.choices.a", "finite"),
        ({"arguments": {f"a{i}": {"field": f"f{i}"} for i in range(17)}}, "arguments", "at most 16"),
        ({"feedback": {"every_s": 0}}, "feedback.every_s", "> 0"),
        ({"feedback": {"every_s": 1, "colour": 2}}, "feedback", "every_s and fields"),
        ({"feedback": {"fields": "distance"}}, "feedback.fields", "list"),
        ({"feedback": {"fields": ["a b"]}}, "feedback.fields", "not a field path"),
        ({"feedback": {"fields": ["a", "a"]}}, "feedback.fields", "twice"),
        ({"spoken": ["go to {where}"]}, "spoken", "not an argument"),
        ({"spoken": ["go to the kitchen"]}, "spoken", "does not say the argument 'place'"),
        ({"spoken": ["go {place"]}, "spoken", "stray brace"),
        ({"spoken": ["go to {place}", "go to {place}"]}, "spoken", "listed twice"),
        ({"spoken": [""]}, "spoken", "phrases of 1..200"),
        ({"spoken": [3]}, "spoken", "phrases of 1..200"),
        ({"spoken": ["a"] * 33}, "spoken", "at most 32"),
        ({"confirm": True}, "spoken", "spoken yes"),
    ],
)
def test_malformed_values_are_refused_naming_the_tool_and_key(
    changes: dict[str, Any], key: str, problem: str
) -> None:
    with pytest.raises(ToolsConfigError) as caught:
        parse_tools_config(one_tool(**changes))
    message = str(caught.value)
    assert message.startswith(f"tool 'go_to': {key}: "), message
    assert problem in message, message


def test_a_spoken_argument_needs_choices_and_forms_are_bounded() -> None:
    speed = {
        "action": "/a",
        "type": "p/action/T",
        "arguments": {"speed": {"field": "v"}},
        "spoken": ["at {speed}"],
    }
    with pytest.raises(
        ToolsConfigError, match=r"tool 'go': spoken: 'at \{speed\}': \{speed\} has no choices"
    ):
        parse_tools_config({"tools": {"go": speed}})
    many = {f"c{i}": {"x": i} for i in range(40)}
    crowd = {
        "action": "/a",
        "type": "p/action/T",
        "arguments": {"a": {"choices": many}, "b": {"choices": many}},
        "spoken": ["{a} {b}"],
    }
    with pytest.raises(ToolsConfigError, match="at most 1024"):
        parse_tools_config({"tools": {"go": crowd}})


@pytest.mark.parametrize(
    ("tools", "problem"),
    [
        ({"robot_command": LOOK}, "reserved"),
        ({"1tool": LOOK}, "invalid name"),
        ({"a" * 65: LOOK}, "invalid name"),
        ({"look": LOOK, "Look": LOOK}, "collides with tool 'look'"),
        ({f"t{i}": LOOK for i in range(65)}, "at most 64"),
        ({"look": "pan@left"}, "expected a mapping"),
    ],
)
def test_bad_tool_names_and_counts_are_refused(tools: dict[str, Any], problem: str) -> None:
    with pytest.raises(ToolsConfigError, match=problem):
        parse_tools_config({"tools": tools})


@pytest.mark.parametrize(
    ("look", "key", "problem"),
    [
        ({"command": "pan@{where}"}, "command", "not an argument"),
        (
            {"arguments": {"direction": {"choices": ["left"]}, "speed": {"choices": ["x"]}}},
            "arguments.speed",
            "not used",
        ),
        ({"command": "pan@{direction}\nlookup"}, "command", "one line"),
        ({"command": ""}, "command", "one line"),
        ({"type": "p/msg/T"}, "type", "no ROS interface"),
        ({"fixed": {"a": 1}}, "fixed", "no ROS interface"),
        ({"arguments": {"direction": {"field": "x"}}}, "arguments.direction.field", "no message fields"),
        (
            {"arguments": {"direction": {"choices": {"left": "left, tenhut"}}}},
            "arguments.direction.choices.left",
            "short word",
        ),
        (
            {"arguments": {"direction": {"choices": {"left": True}}}},
            "arguments.direction.choices.left",
            "short word",
        ),
    ],
)
def test_command_tools_are_checked(look: dict[str, Any], key: str, problem: str) -> None:
    with pytest.raises(ToolsConfigError) as caught:
        parse_tools_config({"tools": {"look": {**LOOK, **look}}})
    assert str(caught.value).startswith(f"tool 'look': {key}: ") and problem in str(caught.value), (
        caught.value
    )


@pytest.mark.parametrize("kind", ["service", "topic"])
def test_feedback_is_for_actions_only(kind: str) -> None:
    middle = "srv" if kind == "service" else "msg"
    tool = {kind: "/x", "type": f"p/{middle}/T", "feedback": {"every_s": 1}}
    with pytest.raises(ToolsConfigError, match="tool 't': feedback: only actions"):
        parse_tools_config({"tools": {"t": tool}})


def test_a_topic_needs_a_message_type() -> None:
    with pytest.raises(ToolsConfigError, match="tool 't': type: a topic needs a message type"):
        parse_tools_config({"tools": {"t": {"topic": "/x", "type": "p/srv/T"}}})
