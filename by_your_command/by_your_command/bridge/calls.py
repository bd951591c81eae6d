"""Service calls and action goals: allow-list rules and the outcome the ROS side reports.

Pure data shared by the config, the core and the node's ROS port (no ROS, no sockets).
"""

from __future__ import annotations

from dataclasses import dataclass

from by_your_command.bridge.protocol import normalize_interface

__all__ = [
    "ActionRule",
    "CallOutcome",
    "ServiceRule",
    "GOAL_ABORTED",
    "GOAL_CANCELED",
    "GOAL_SUCCEEDED",
    "GOAL_UNKNOWN",
    "normalize_interface",
]

DEFAULT_CALL_TIMEOUT_S = 10.0
# action_msgs/msg/GoalStatus codes the bridge reports (the rest only exist while a goal runs).
GOAL_UNKNOWN = 0
GOAL_SUCCEEDED = 4
GOAL_CANCELED = 5
GOAL_ABORTED = 6


@dataclass(frozen=True)
class ServiceRule:
    """One allow-listed service."""

    name: str  # as configured (relative or absolute), resolved like topics
    type: str  # normalised pkg/srv/T
    timeout_s: float = DEFAULT_CALL_TIMEOUT_S  # the longest a call may wait for the server and its response


@dataclass(frozen=True)
class ActionRule:
    """One allow-listed action."""

    name: str
    type: str  # normalised pkg/action/T
    timeout_s: float = DEFAULT_CALL_TIMEOUT_S  # wait for the server + the goal's acceptance


@dataclass(frozen=True)
class CallOutcome:
    """A service's response or an action goal's end, as the graph reports it."""

    ok: bool
    values_json: str = "{}"  # JSON object text of the response / result fields when ok (encoded once)
    error: str = ""  # failure text for the client
    code: str = ""  # no_server | rejected | timeout | cancelled | internal_error | bad_args
    status: int = GOAL_UNKNOWN  # actions: action_msgs/GoalStatus (4 succeeded, 5 canceled, 6 aborted)
