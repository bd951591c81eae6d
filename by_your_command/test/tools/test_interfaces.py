"""ros/interfaces.describe on installed types: fields, nesting, arrays, constants, parts."""

from __future__ import annotations

import pytest

from by_your_command.ros.interfaces import describe
from by_your_command.tools.interface_types import Constant, InterfaceError

pytestmark = pytest.mark.unit


def test_a_message_with_nested_messages_and_time() -> None:
    interface = describe("geometry_msgs/msg/PoseStamped")
    assert (interface.type, interface.kind, [p for p, _ in interface.parts]) == (
        "geometry_msgs/msg/PoseStamped",
        "msg",
        ["message"],
    )
    message = interface.input
    assert [f.name for f in message.fields] == ["header", "pose"]
    header = message.field("header")
    assert header is not None and header.kind == "message" and header.message is not None
    assert header.message.type == "std_msgs/msg/Header"
    stamp = message.find("header.stamp")
    assert stamp is not None and stamp.message is not None
    assert stamp.message.type == "builtin_interfaces/msg/Time"
    assert [(f.name, f.kind) for f in stamp.message.fields] == [("sec", "int32"), ("nanosec", "uint32")]
    x = message.find("pose.position.x")
    assert x is not None and (x.kind, x.container) == ("double", "")
    assert message.find("pose.position.nope") is None and message.find("header.frame_id.x") is None


def test_short_names_mean_messages_and_basic_kinds() -> None:
    assert describe("std_msgs/String").input.fields[0].kind == "string"
    assert describe("std_msgs/msg/Bool").input.fields[0].kind == "boolean"
    assert describe("std_msgs/msg/Float32").input.fields[0].kind == "float"


def test_arrays_sequences_and_byte_data() -> None:
    info = describe("sensor_msgs/msg/CameraInfo").input
    d, k = info.field("d"), info.field("k")
    assert d is not None and (d.kind, d.container, d.size) == ("double", "sequence", None)
    assert k is not None and (k.kind, k.container, k.size) == ("double", "array", 9)
    data = describe("sensor_msgs/msg/Image").input.field("data")
    assert data is not None and (data.kind, data.container) == ("uint8", "sequence")
    names = describe("sensor_msgs/msg/JointState").input.field("name")
    assert names is not None and (names.kind, names.container) == ("string", "sequence")


def test_bounded_strings_and_constants() -> None:
    bounded = describe("type_description_interfaces/msg/FieldType").input.field("nested_type_name")
    assert bounded is not None and (bounded.kind, bounded.string_bound) == ("string", 255)
    status = describe("sensor_msgs/msg/NavSatStatus").input
    assert Constant("STATUS_FIX", 0) in status.constants
    assert Constant("STATUS_NO_FIX", -1) in status.constants
    assert not any("DEFAULT" in c.name for c in status.constants)  # X__DEFAULT are defaults
    assert {f.name for f in status.fields} == {"status", "service"}


def test_a_service_has_request_and_response() -> None:
    cancel = describe("action_msgs/srv/CancelGoal")
    assert (cancel.kind, [p for p, _ in cancel.parts]) == ("srv", ["request", "response"])
    response = cancel.part("response")
    goals = response.field("goals_canceling")
    assert goals is not None and (goals.kind, goals.container) == ("message", "sequence")
    assert Constant("ERROR_REJECTED", 1) in response.constants
    uuid = cancel.input.find("goal_info.goal_id.uuid")
    assert uuid is not None and (uuid.kind, uuid.container, uuid.size) == ("uint8", "array", 16)


def test_the_package_test_interfaces() -> None:
    navigate = describe("by_your_command_msgs/action/NavigateToPose")
    assert [p for p, _ in navigate.parts] == ["goal", "result", "feedback"]
    assert [f.name for f in navigate.input.fields] == ["pose", "behavior_tree"]
    feedback = navigate.part("feedback")
    remaining = feedback.field("distance_remaining")
    assert remaining is not None and remaining.kind == "float"
    duration = feedback.field("navigation_time")
    assert duration is not None and duration.message is not None
    assert duration.message.type == "builtin_interfaces/msg/Duration"
    assert [(f.name, f.kind) for f in navigate.part("result").fields] == [
        ("error_code", "uint16"),
        ("error_msg", "string"),
    ]
    trigger = describe("by_your_command_msgs/srv/Trigger")
    assert trigger.input.fields == ()
    assert [f.name for f in trigger.part("response").fields] == ["success", "message"]


@pytest.mark.parametrize(
    ("name", "problem"),
    [
        ("no_such_pkg/msg/T", "not installed"),
        ("std_msgs/msg/NoSuchType", "not installed"),
        ("std_msgs/srv/String", "not installed"),
        ("std_msgs", "invalid interface type"),
        ("std_msgs/blah/String", "invalid interface type"),
        ("../x/msg/T", "invalid interface type"),
        ("a/msg/" + "T" * 300, "invalid interface type"),
    ],
)
def test_unknown_types_are_clear_errors(name: str, problem: str) -> None:
    with pytest.raises(InterfaceError, match=problem):
        describe(name)


def test_a_message_is_not_an_action() -> None:
    with pytest.raises(InterfaceError, match="not installed"):
        describe("geometry_msgs/action/PoseStamped")
