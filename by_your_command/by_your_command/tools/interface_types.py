"""ROS interface definitions as plain data: what ros/interfaces.py reads from the generated classes
and what the catalog code works on without ROS (so agents and tests need no rosidl)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

InterfaceKind = Literal["msg", "srv", "action"]
Container = Literal["", "sequence", "array"]
PART_NAMES: dict[str, tuple[str, ...]] = {
    "msg": ("message",),
    "srv": ("request", "response"),
    "action": ("goal", "result", "feedback"),
}
# The part a tool fills: a topic's message, a service's request, an action's goal.
INPUT_PART: dict[str, str] = {"msg": "message", "srv": "request", "action": "goal"}

INT_RANGES: dict[str, tuple[int, int]] = {
    "int8": (-(2**7), 2**7 - 1),
    "uint8": (0, 2**8 - 1),
    "char": (0, 2**8 - 1),
    "octet": (0, 2**8 - 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}
FLOAT32_MAX = 3.4028234663852886e38
FLOAT_KINDS = ("float", "double")
BYTE_KINDS = ("uint8", "char", "octet")  # sequences of these travel as base64 text (rosbridge)
SCALAR_KINDS = ("boolean", *INT_RANGES, *FLOAT_KINDS, "wchar", "string", "wstring")


class InterfaceError(ValueError):
    """A type that is not installed or that cannot be described."""


@dataclass(frozen=True)
class Constant:
    name: str
    value: bool | int | float | str


@dataclass(frozen=True)
class Field:
    name: str
    kind: str  # one of SCALAR_KINDS, or "message" (then `message` describes it)
    ros_type: str  # as the interface spells it: "float", "sequence<double, 5>", "std_msgs/Header"
    container: Container = ""
    size: int | None = None  # array: its exact length; sequence: its bound (None: unbounded)
    string_bound: int | None = None  # string<N> (of the element, for a sequence of strings)
    message: Message | None = None


@dataclass(frozen=True)
class Message:
    type: str  # pkg/msg/T, or pkg/srv/T_Request, pkg/action/T_Goal… for parts
    fields: tuple[Field, ...] = ()
    constants: tuple[Constant, ...] = ()

    def field(self, name: str) -> Field | None:
        return next((f for f in self.fields if f.name == name), None)

    def find(self, path: str) -> Field | None:
        """The field at a dotted path through nested messages (`pose.pose.position.x`), or None."""
        message: Message | None = self
        found: Field | None = None
        for name in path.split("."):
            if message is None:
                return None
            found = message.field(name)
            if found is None:
                return None
            message = found.message if found.container == "" else None
        return found


@dataclass(frozen=True)
class Interface:
    type: str  # normalised pkg/msg/T, pkg/srv/T or pkg/action/T
    kind: InterfaceKind
    parts: tuple[tuple[str, Message], ...]  # ("goal", …), ("result", …), ("feedback", …)

    def part(self, name: str) -> Message:
        for part, message in self.parts:
            if part == name:
                return message
        raise InterfaceError(f"{self.type} has no {name} part")

    @property
    def input(self) -> Message:
        """What a tool sends: the message, the request or the goal."""
        return self.part(INPUT_PART[self.kind])
