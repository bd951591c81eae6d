"""Hostile YAML documents: random values in a plausible layout, damaged text, bombs and oddities."""

from __future__ import annotations

from typing import Any

import yaml
from fuzzing import JSON_VALUES, ODD_TEXT
from hypothesis import strategies as st

YAML_SCALARS = (
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | ODD_TEXT
    | st.sampled_from(["", "yes", "no", "~", "0x1F", "1e400", ".nan", "-.inf", "2020-01-01", "{{", "}}"])
)
PLAIN = JSON_VALUES.filter(lambda v: not isinstance(v, float) or v == v) | YAML_SCALARS


def alias_bomb(levels: int, fanout: int, leaf: str = "x") -> str:
    """The billion laughs: each anchor names the previous one `fanout` times (shared when loaded)."""
    lines = [f"b0: &b0 {leaf!r}"]
    for level in range(1, levels):
        lines.append(f"b{level}: &b{level} [" + ", ".join([f"*b{level - 1}"] * fanout) + "]")
    return "\n".join(lines) + "\n"


def mapping_bomb(levels: int, fanout: int, under: str) -> str:
    """Nested mappings sharing one another `fanout` times per level, hung under key `under`."""
    lines = ["m0: &m0 {k: v}"]
    for level in range(1, levels):
        lines.append(
            f"m{level}: &m{level} {{" + ", ".join(f"k{i}: *m{level - 1}" for i in range(fanout)) + "}"
        )
    lines.append(f"{under}: *m{levels - 1}")
    return "\n".join(lines) + "\n"


ODDITIES = [
    "",
    "---\n...\n",
    "--- a\n--- b\n",  # two documents
    "[1, 2",
    "a: b: c",
    "\t- tab indented",
    "a: 1\na: 2\n",  # duplicate key
    "? [a, b]\n: complex key\n",
    "!!python/object/apply:os.system ['true']\n",
    "a: !!binary AAAA\n",
    "a: !custom x\n",
    "a: &x 1\nb: *y\n",  # unknown alias
    "<<: {a: 1}\n",
    "a: [" * 3000 + "]" * 3000,
    "a: " + "{b: " * 2000 + "1" + "}" * 2000,
    "x" * 2_000_000,  # over the 1 MiB file limit
    "a: '" + "é" * 100_000 + "'\n",
    "\ufeffa: 1\n",
    "a: \x00\n",
    "a: \x85\n",
    alias_bomb(9, 9),
]
ODD_BYTES = [b"\xff\xfe\x00a\x00:", b"a: \xc3\x28\n", b"\x00" * 64, "a: é".encode("latin-1")]


def dump(value: Any) -> str:
    try:
        return yaml.safe_dump(value, allow_unicode=True, sort_keys=False)
    except yaml.YAMLError:
        return repr(value)


@st.composite
def damaged(draw: st.DrawFn, text: str) -> str:
    """Insert, delete or truncate at a random place: indentation and quoting break in many ways."""
    at = draw(st.integers(0, len(text)))
    kind = draw(st.integers(0, 3))
    if kind == 0:
        return text[:at]
    if kind == 1:
        return (
            text[:at]
            + draw(st.sampled_from([":", "- ", "  ", "\t", "&a ", "*a", "!!str ", "'", '"', "{", "[", "\n"]))
            + text[at:]
        )
    if kind == 2:
        return text[:at] + text[at + draw(st.integers(1, 10)) :]
    return text + draw(st.sampled_from(ODDITIES[:14]))


def documents(layout: st.SearchStrategy[Any]) -> st.SearchStrategy[str | bytes]:
    """A plausible document, a damaged one, a random one, or one of the known oddities."""
    text = layout.map(dump)
    odd = (
        text.flatmap(damaged)
        | PLAIN.map(dump)
        | st.sampled_from(ODDITIES)
        | st.sampled_from(ODD_BYTES)
        | st.text(max_size=200)
    )
    return st.integers(0, 3).flatmap(lambda pick: odd if pick == 2 else text)


def sometimes_wrong(strategy: st.SearchStrategy[Any]) -> st.SearchStrategy[Any]:
    """Mostly the plausible value, now and then any value at all."""
    return st.integers(0, 7).flatmap(lambda pick: PLAIN if pick == 5 else strategy)
