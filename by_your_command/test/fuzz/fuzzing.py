"""Shared pieces of the hostile-input suite: the two modes, the inputs-tried tally, frame strategies.

Short mode (default): a few derandomized examples per target, so `make test` stays fast and
deterministic. Long mode (`BYC_FUZZ_LONG=1`): each target's `long` count, random seeds, at least
100k inputs in all (docs/reliability.md, "Hostile input").
"""

from __future__ import annotations

import json
import os
import statistics
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

LONG = os.environ.get("BYC_FUZZ_LONG", "") not in ("", "0")


def fuzz_settings(short: int, long: int) -> settings:
    """`short` examples in `make test` (derandomized: the same inputs every run), `long` in long mode."""
    return settings(
        max_examples=long if LONG else short,
        deadline=None,  # no timing assertions: hangs are caught by waits with generous bounds
        derandomize=not LONG,
        database=None,
        suppress_health_check=[
            HealthCheck.too_slow,
            HealthCheck.data_too_large,
            HealthCheck.filter_too_much,
            HealthCheck.large_base_example,
        ],
    )


@dataclass
class _Target:
    inputs: int = 0
    failures: int = 0
    seconds: float = 0.0
    durations: list[float] = field(default_factory=list)  # per input


class Tally:
    """Inputs tried per target, how many failed, and how long each took (reported, never asserted)."""

    def __init__(self) -> None:
        self._targets: dict[str, _Target] = {}

    def __bool__(self) -> bool:
        return bool(self._targets)

    @contextmanager
    def input(self, target: str, count: int = 1) -> Iterator[None]:
        """One example of `target` (`count` inputs when it feeds several, e.g. a frame sequence)."""
        entry = self._targets.setdefault(target, _Target())
        start = time.perf_counter()
        try:
            yield
        except BaseException:
            entry.failures += 1
            raise
        finally:
            elapsed = time.perf_counter() - start
            entry.inputs += count
            entry.seconds += elapsed
            entry.durations.append(elapsed / count)

    def rows(self) -> list[dict[str, Any]]:
        return [
            {
                "target": name,
                "inputs": entry.inputs,
                "failures": entry.failures,
                "seconds": entry.seconds,
                "median_ms": 1000 * statistics.median(entry.durations) if entry.durations else 0.0,
                "max_ms": 1000 * max(entry.durations, default=0.0),
            }
            for name, entry in sorted(self._targets.items())
        ]


TALLY = Tally()

# --- JSON and rosbridge frames ------------------------------------------------------------------

ODD_TEXT = st.text(
    alphabet=st.characters(codec="utf-8", exclude_categories=()) | st.sampled_from("\u200b\u202e\ufeff\x00"),
    max_size=40,
)
SCALARS = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.integers(min_value=-(2**70), max_value=2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | ODD_TEXT
)
JSON_VALUES = st.recursive(
    SCALARS,
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(ODD_TEXT, inner, max_size=6),
    max_leaves=25,
)
OPS = ["subscribe", "unsubscribe", "advertise", "unadvertise", "publish", "call_service", "fragment", ""]
KEYS = ["op", "id", "topic", "type", "msg", "throttle_rate", "queue_length", "compression", "fragment_size"]


def valid_frames(subscribable: list[str], publishable: list[str]) -> st.SearchStrategy[dict[str, Any]]:
    """Well-formed requests on the given topics (the starting point of the mutations)."""
    ids = st.none() | st.integers(-(2**63) + 1, 2**63 - 1) | st.text(max_size=20)

    def with_id(frame: dict[str, Any], request_id: Any) -> dict[str, Any]:
        return frame if request_id is None else {**frame, "id": request_id}

    subscribe = st.builds(
        lambda topic, throttle, queue, request_id: with_id(
            {"op": "subscribe", "topic": topic, "throttle_rate": throttle, "queue_length": queue}, request_id
        ),
        st.sampled_from(subscribable),
        st.integers(0, 1000),
        st.integers(0, 50),
        ids,
    )
    unsubscribe = st.builds(
        lambda topic, request_id: with_id({"op": "unsubscribe", "topic": topic}, request_id),
        st.sampled_from(subscribable),
        ids,
    )
    publish = st.builds(
        lambda topic, data, request_id: with_id(
            {"op": "publish", "topic": topic, "msg": {"data": data}}, request_id
        ),
        st.sampled_from(publishable),
        st.text(max_size=30),
        ids,
    )
    advertise = st.builds(
        lambda topic, request_id: with_id(
            {"op": "advertise", "topic": topic, "type": "std_msgs/String"}, request_id
        ),
        st.sampled_from(publishable),
        ids,
    )
    return subscribe | unsubscribe | publish | advertise


@st.composite
def mutated_objects(draw: st.DrawFn, valid: st.SearchStrategy[dict[str, Any]]) -> Any:
    """A valid request with 1-3 structural mutations: wrong types, missing, extra or odd fields,
    unknown ops, deep nesting, huge arrays, non-objects."""
    frame: Any = dict(draw(valid))
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.integers(0, 8))
        if not isinstance(frame, dict):
            break
        key = draw(st.sampled_from(KEYS) | ODD_TEXT)
        if kind == 0:
            frame.pop(key, None)
        elif kind == 1:
            frame[key] = draw(JSON_VALUES)
        elif kind == 2:
            frame["op"] = draw(st.sampled_from(OPS) | JSON_VALUES)
        elif kind == 3:
            depth = draw(st.integers(1, 200))
            leaf: Any = draw(SCALARS)
            for _ in range(depth):
                leaf = [leaf] if draw(st.booleans()) else {"a": leaf}
            frame[key] = leaf
        elif kind == 4:
            frame[key] = [draw(SCALARS)] * draw(st.integers(0, 5000))
        elif kind == 5:
            frame["msg"] = {
                "data": draw(JSON_VALUES),
                **draw(st.dictionaries(ODD_TEXT, JSON_VALUES, max_size=3)),
            }
        elif kind == 6:
            frame[key] = draw(
                st.sampled_from([float("nan"), float("inf"), -float("inf"), 2**64, -(2**63) - 1])
            )
        elif kind == 7:
            frame["topic"] = draw(
                st.sampled_from(["", "/", "//x", "~private", "a" * 300, "prompt_text\n", "/robot1/../x"])
                | ODD_TEXT
            )
        else:
            frame = draw(st.sampled_from([[frame], frame.get("op"), len(frame), None]))
    return frame


def to_text(value: Any) -> str:
    """JSON text; NaN/Infinity come out as the bare literals Python's json writes (not JSON)."""
    return json.dumps(value, allow_nan=True, ensure_ascii=False)


TEXT_MUTATIONS = [
    "truncate",
    "insert",
    "flip",
    "huge_int",
    "huge_float",
    "deep",
    "wide",
    "escape",
    "bom",
    "nan",
]


@st.composite
def mutated_text(draw: st.DrawFn, base: str) -> str:
    """Byte-level damage to a serialized frame."""
    text = base
    for _ in range(draw(st.integers(1, 2))):
        kind = draw(st.sampled_from(TEXT_MUTATIONS))
        at = draw(st.integers(0, len(text)))
        if kind == "truncate":
            text = text[:at]
        elif kind == "insert":
            text = (
                text[:at]
                + draw(st.text(max_size=8) | st.sampled_from(['"', "}", "]", ",", ":", "\\"]))
                + text[at:]
            )
        elif kind == "flip" and text:
            at = min(at, len(text) - 1)
            text = text[:at] + chr((ord(text[at]) + draw(st.integers(1, 200))) % 0x10FFFF) + text[at + 1 :]
        elif kind == "huge_int":
            text = text[:at] + "9" * draw(st.sampled_from([20, 4299, 4301, 10_000])) + text[at:]
        elif kind == "huge_float":
            text = (
                text[:at]
                + draw(st.sampled_from(["1e400", "-1e400", "1." + "0" * 100, "1e-400", "0e99999"]))
                + text[at:]
            )
        elif kind == "deep":
            depth = draw(st.sampled_from([31, 32, 33, 100, 5000, 100_000]))
            text = text[:at] + "[" * depth + "]" * depth + text[at:]
        elif kind == "wide":
            text = text[:at] + "[" + "0," * draw(st.sampled_from([1000, 100_000])) + "0]" + text[at:]
        elif kind == "escape":
            text = (
                text[:at]
                + draw(st.sampled_from(["\\ud800", "\\udfff\\ud800", "\\u0000", "\\x41", "\\"]))
                + text[at:]
            )
        elif kind == "bom":
            text = "\ufeff" + text
        else:
            text = text.replace("0", "NaN", 1) if "0" in text else text + "Infinity"
    return text


def hostile_frames(subscribable: list[str], publishable: list[str]) -> st.SearchStrategy[str | bytes]:
    """Random and mutated rosbridge frames, as text or as bytes (binary WebSocket frames)."""
    valid = valid_frames(subscribable, publishable)
    objects = mutated_objects(valid).map(to_text)
    damaged = valid.map(to_text).flatmap(mutated_text)
    random_json = JSON_VALUES.map(to_text)
    frames = objects | damaged | random_json | st.text(max_size=200) | valid.map(to_text)
    as_bytes = frames.flatmap(
        lambda text: st.sampled_from(["utf-8", "utf-16", "utf-32", "latin-1"]).map(
            lambda codec: text.encode(codec, "surrogatepass" if codec.startswith("utf") else "replace")
        )
    )
    return frames | as_bytes | st.binary(max_size=200)
