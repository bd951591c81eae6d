"""Topic name resolution: relative names live in the bridge's namespace; matching is exact."""

from __future__ import annotations

import re

_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def resolve_topic(name: str, namespace: str) -> str:
    """`prompt_voice` in `/robot1` → `/robot1/prompt_voice`; absolute names stay as they are.

    Raises ValueError for names ROS would reject (empty tokens, `~`, odd characters), so the
    client gets a clear error instead of a subscription to something unexpected.
    """
    if not name or name.endswith("/"):
        raise ValueError(f"invalid topic name {name!r}")
    if name.startswith("~"):
        raise ValueError(f"private topic names are not served: {name!r}")
    if name.startswith("/"):
        full = name
    else:
        full = f"{namespace.rstrip('/')}/{name}"
    tokens = full.split("/")[1:]
    if not tokens or not all(_NAME_RE.match(token) for token in tokens):
        raise ValueError(f"invalid topic name {name!r}")
    return full
