"""Hostile `msg` objects for the bridge's publishable ROS types, and publish frames carrying them."""

from __future__ import annotations

from typing import Any

from byc_testing import REPO_ROOT
from fuzzing import JSON_VALUES, ODD_TEXT, to_text
from hypothesis import strategies as st

from by_your_command.bridge.config import load_allow_lists
from by_your_command.ros.convert import message_class

ALLOW = load_allow_lists(REPO_ROOT / "by_your_command" / "config" / "bridge.yaml")
PUBLISH_CLASSES = {rule.type: message_class(rule.type) for rule in ALLOW.publish}


def field_values(kind: str, depth: int = 0) -> st.SearchStrategy[Any]:
    """Values for a ROS field of `kind`: mostly plausible, some out of range or of the wrong type."""
    wrong = JSON_VALUES
    if kind.startswith("sequence<") or kind.endswith("]"):
        element = kind.removeprefix("sequence<").split(",")[0].rstrip(">").split("[")[0]
        as_list = st.lists(field_values(element, depth + 1), max_size=20)
        huge = st.sampled_from([[0] * 70_000, [32767, -32768, 32768], [True, 1], [1.5]])
        base64 = st.sampled_from(["", "AAAA", "AAA", "!!!!", "QUJD\n", "=" * 8])
        return as_list | huge | base64 | wrong
    if "/" in kind:
        if depth > 3:
            return wrong
        return message_dicts(kind, depth + 1) | wrong
    if kind in ("float", "double"):
        return st.floats(allow_nan=False) | st.none() | st.sampled_from([1e300, -1e300, 2**1100]) | wrong
    if kind == "boolean":
        return st.booleans() | wrong
    if kind in ("string", "wstring") or kind.startswith("string<"):
        return ODD_TEXT | st.sampled_from(["\ud800", "x" * 100_000]) | wrong
    return st.integers(-(2**65), 2**65) | st.integers(-1, 256) | wrong


def message_dicts(type_name: str, depth: int = 0) -> st.SearchStrategy[dict[str, Any]]:
    fields = message_class(type_name).get_fields_and_field_types()
    chosen = st.fixed_dictionaries(
        {}, optional={name: field_values(kind, depth) for name, kind in fields.items()}
    )
    extra = st.dictionaries(ODD_TEXT, JSON_VALUES, max_size=2)
    return st.one_of(chosen, st.builds(lambda a, b: {**a, **b}, chosen, extra))


@st.composite
def publish_frames(draw: st.DrawFn) -> str:
    rule = draw(st.sampled_from(ALLOW.publish))
    return to_text({"op": "publish", "topic": rule.topic, "msg": draw(message_dicts(rule.type))})
