"""Field trees: dotted paths (`pose.header.frame_id: map`) expanded to nested dicts, leaf paths,
overlaps between them, and deep merges where what is already set wins (fixed fields)."""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Iterator
from typing import Any

FIELD_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,63}$")  # a ROS field name (one path component)
MAX_DEPTH = 32  # nesting of any value from a file, a catalog or a model


class ValueProblem(ValueError):
    """A malformed field tree; the caller adds where it came from."""


def check_path(path: str) -> tuple[str, ...]:
    parts = tuple(path.split(".")) if isinstance(path, str) else ()
    if not parts or not all(FIELD_NAME.match(part) for part in parts) or len(parts) > MAX_DEPTH:
        raise ValueProblem(
            f"{str(path)[:80]!r} is not a field path (names joined by dots, e.g. pose.header.frame_id)"
        )
    return parts


def check_plain(value: Any, where: str, depth: int = 0) -> None:
    """JSON-like data only (dict with str keys, list, str, finite number, bool), not too deep."""
    if depth > MAX_DEPTH:
        raise ValueProblem(f"{where}: nested more than {MAX_DEPTH} deep")
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                raise ValueProblem(f"{where}: key {key!r} is not text")
            check_plain(item, f"{where}.{key}", depth + 1)
    elif isinstance(value, list):
        for index, item in enumerate(value):
            check_plain(item, f"{where}[{index}]", depth + 1)
    elif isinstance(value, float):
        if not math.isfinite(value):
            raise ValueProblem(f"{where}: {value} is not a finite number")
    elif not isinstance(value, (str, int, bool)):
        raise ValueProblem(f"{where}: {type(value).__name__} values are not allowed")


def expand(tree: Any, where: str) -> dict[str, Any]:
    """`{"pose.header.frame_id": "map", "pose": {"pose.position.x": 1}}` → nested dicts. A field
    given twice (`pose.x` and `pose: {x: …}` alike) is an error, never a silent override."""
    if not isinstance(tree, dict):
        raise ValueProblem(f"{where}: expected a mapping of field paths to values")
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if not isinstance(key, str):
            raise ValueProblem(f"{where}: key {key!r} is not a field path")
        parts = check_path(key)
        inner = expand(value, f"{where}.{key}") if isinstance(value, dict) else value
        check_plain(inner, f"{where}.{key}", len(parts))
        put(out, parts, inner, f"{where}.{key}")
    return out


def put(tree: dict[str, Any], parts: tuple[str, ...], value: Any, where: str) -> None:
    """Set `value` at `parts`, merging nested dicts; a leaf set twice is a ValueProblem."""
    node = tree
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ValueProblem(f"{where}: {part!r} is already set to a value")
        node = child
    last = parts[-1]
    if last not in node:
        node[last] = value
    elif isinstance(node[last], dict) and isinstance(value, dict):
        for key, item in value.items():
            put(node[last], (key,), item, where)
    else:
        raise ValueProblem(f"{where}: {'.'.join(parts)!r} is set twice")


def leaf_paths(tree: Any, prefix: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    """Paths of the leaves (non-dict values and empty dicts)."""
    if isinstance(tree, dict) and tree:
        for key, value in tree.items():
            yield from leaf_paths(value, (*prefix, key))
    else:
        yield prefix


def overlap(first: set[tuple[str, ...]], second: set[tuple[str, ...]]) -> tuple[str, ...] | None:
    """A path of `first` equal to, inside or around a path of `second` (they would set the same
    field), or None."""
    for a in first:
        for b in second:
            if a[: len(b)] == b or b[: len(a)] == a:
                return a if len(a) >= len(b) else b
    return None


def merge_into(target: dict[str, Any], addition: dict[str, Any]) -> None:
    """Deep merge where what `target` already has wins (fixed fields are never overridden)."""
    for key, value in addition.items():
        if key not in target:
            target[key] = copy.deepcopy(value)
        elif isinstance(target[key], dict) and isinstance(value, dict):
            merge_into(target[key], value)


def placed(field: str, value: Any) -> dict[str, Any]:
    """`value` under the dotted `field` ("" = merged at the top: value must be a dict)."""
    if not field:
        return value if isinstance(value, dict) else {}
    tree: dict[str, Any] = {}
    put(tree, tuple(field.split(".")), value, field)
    return tree


def depth_of(value: Any, limit: int = MAX_DEPTH + 1) -> int:
    """Nesting depth of lists/dicts, counting at most to `limit` (no deep recursion)."""
    deepest, level = 0, [value]
    while level and deepest < limit:
        children: list[Any] = []
        for item in level:
            if isinstance(item, dict):
                children.extend(item.values())
            elif isinstance(item, list):
                children.extend(item)
        if not children:
            break
        deepest += 1
        level = children
    return deepest
