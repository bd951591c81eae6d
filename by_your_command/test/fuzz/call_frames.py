"""Hostile `call_service`, `send_action_goal` and `cancel_action_goal` frames (issue 35)."""

from __future__ import annotations

from typing import Any

from fuzzing import JSON_VALUES, ODD_TEXT, SCALARS, to_text
from hypothesis import strategies as st

IDS = st.integers(-(2**63) + 1, 2**63 - 1) | st.text(max_size=20)
CALL_KEYS = [
    "op",
    "id",
    "service",
    "action",
    "type",
    "action_type",
    "args",
    "timeout",
    "feedback",
    "compression",
]
TYPES = st.sampled_from(
    ["std_srvs/srv/Trigger", "std_srvs/Trigger", "nav2_msgs/action/NavigateToPose", "a/msg/B", "x", ""]
)


def valid_calls(services: list[str], actions: list[str]) -> st.SearchStrategy[dict[str, Any]]:
    """Well-formed call ops on the given names (allowed or not): the starting point of mutations."""
    args = st.dictionaries(ODD_TEXT, JSON_VALUES, max_size=4)
    call = st.builds(
        lambda name, request_id, values, timeout: {
            "op": "call_service",
            "id": request_id,
            "service": name,
            "args": values,
            **({} if timeout is None else {"timeout": timeout}),
        },
        st.sampled_from(services),
        IDS,
        args,
        st.none() | st.floats(0.001, 3600),
    )
    goal = st.builds(
        lambda name, request_id, values, feedback: {
            "op": "send_action_goal",
            "id": request_id,
            "action": name,
            "action_type": "nav2_msgs/action/NavigateToPose",
            "args": values,
            "feedback": feedback,
        },
        st.sampled_from(actions),
        IDS,
        args,
        st.booleans(),
    )
    cancel = st.builds(
        lambda name, request_id: {"op": "cancel_action_goal", "id": request_id, "action": name},
        st.sampled_from(actions),
        IDS,
    )
    return call | goal | cancel


@st.composite
def mutated_calls(draw: st.DrawFn, valid: st.SearchStrategy[dict[str, Any]]) -> dict[str, Any]:
    """1-3 field mutations: missing, wrong-typed, odd or huge values, another op's fields."""
    frame = dict(draw(valid))
    for _ in range(draw(st.integers(1, 3))):
        key = draw(st.sampled_from(CALL_KEYS) | ODD_TEXT)
        kind = draw(st.integers(0, 4))
        if kind == 0:
            frame.pop(key, None)
        elif kind == 1:
            frame[key] = draw(JSON_VALUES)
        elif kind == 2:
            frame[key] = draw(TYPES | SCALARS)
        elif kind == 3:
            frame[key] = draw(
                st.sampled_from([float("nan"), float("inf"), 0, -1, 3601, 1e300, True, "", "a" * 300])
            )
        else:
            frame[key] = draw(
                st.sampled_from(["", "/", "//x", "~private", "a" * 300, "x\n", "/robot1/../x"]) | ODD_TEXT
            )
    return frame


def call_frames(services: list[str], actions: list[str]) -> st.SearchStrategy[str]:
    valid = valid_calls(services, actions)
    return (valid | mutated_calls(valid)).map(to_text)
