"""What both emulators' scripts share: the replies a scripted turn can give, and the strict YAML
parsing of a script (`parse_script`). Each vendor's module keeps its own `Turn` (its faults) and
`Script` (its limits) and names the keys that fill them."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, TypeVar

import yaml

Modality = Literal["auto", "audio", "text"]
T = TypeVar("T")
ScriptT = TypeVar("ScriptT")
TurnT = TypeVar("TurnT")


@dataclass(frozen=True)
class Say:
    """The model's words. `modality` auto follows the session's output modalities; `text` answers in
    text even in an audio session (a text-only reply)."""

    text: str
    modality: Modality = "auto"


@dataclass(frozen=True)
class CallTool:
    """A function call; `then` answers once the client sent the tool output."""

    name: str
    arguments: str  # JSON text, as the model writes it
    then: Say = field(default_factory=lambda: Say("Done."))


@dataclass(frozen=True)
class Silence:
    """Never answer: the reply starts and then nothing comes until the client cancels it."""


Reply = Say | CallTool | Silence

TURN_KEYS = frozenset({"heard", "say", "text", "tool", "then", "silent"})


class ScriptError(ValueError):
    """A script file that does not describe a script; the message names the offending place."""


_KIND_NAMES = {str: "a string", int: "an integer", float: "a number", bool: "true or false"}


def typed(value: object, kind: type[T], where: str) -> T:
    """`value` if it is a `kind` (an int is a float too; a bool is never an int)."""
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)  # type: ignore[return-value]
    if kind is int and isinstance(value, bool):
        raise ScriptError(f"{where}: expected an integer, got bool")
    if not isinstance(value, kind):
        expected = _KIND_NAMES.get(kind, kind.__name__)
        raise ScriptError(f"{where}: expected {expected}, got {type(value).__name__}")
    return value


def optional_int(raw: Mapping[str, object], key: str, where: str) -> int | None:
    value = raw.get(key)
    return None if value is None else typed(value, int, f"{where}.{key}")


def strings(raw: Mapping[str, object], key: str) -> tuple[str, ...]:
    values = raw.get(key, [])
    if not isinstance(values, list):
        raise ScriptError(f"script.{key}: expected a list of strings")
    return tuple(typed(value, str, f"script.{key}[{i}]") for i, value in enumerate(values))


def parse_say(value: object, where: str) -> Say:
    if isinstance(value, str):
        return Say(value)
    if isinstance(value, Mapping) and len(value) == 1 and set(value) <= {"say", "text"}:
        key, text = next(iter(value.items()))
        return Say(typed(text, str, f"{where}.{key}"), "auto" if key == "say" else "text")
    raise ScriptError(f"{where}: expected a string or {{say: ...}} / {{text: ...}}")


def check_turn_keys(raw: object, where: str, known: frozenset[str]) -> Mapping[str, object]:
    if not isinstance(raw, Mapping):
        raise ScriptError(f"{where}: expected a mapping")
    unknown = set(raw) - known
    if unknown:
        raise ScriptError(f"{where}: unknown key(s) {sorted(unknown)}; known: {sorted(known)}")
    return raw


def parse_reply(raw: Mapping[str, object], where: str) -> Reply:
    """The one reply of a turn mapping: say, text, tool (+ then) or silent."""
    kinds = [key for key in ("say", "text", "tool", "silent") if key in raw]
    if len(kinds) != 1:
        raise ScriptError(f"{where}: give exactly one of say, text, tool, silent (got {kinds})")
    reply: Reply
    if kinds[0] in ("say", "text"):
        reply = parse_say({kinds[0]: raw[kinds[0]]}, where)
    elif kinds[0] == "silent":
        reply = Silence()
    else:
        tool = raw["tool"]
        if not isinstance(tool, Mapping) or set(tool) - {"name", "arguments"} or "name" not in tool:
            raise ScriptError(f"{where}.tool: expected {{name: ..., arguments: {{...}}}}")
        arguments = tool.get("arguments", {})
        if not isinstance(arguments, (str, Mapping)):
            raise ScriptError(f"{where}.tool.arguments: expected a mapping (or JSON text)")
        text = arguments if isinstance(arguments, str) else json.dumps(dict(arguments))
        then = parse_say(raw["then"], f"{where}.then") if "then" in raw else Say("Done.")
        reply = CallTool(typed(tool["name"], str, f"{where}.tool.name"), text, then)
    if "then" in raw and not isinstance(reply, CallTool):
        raise ScriptError(f"{where}: `then` only follows a tool call")
    return reply


def turn_list(raw: Mapping[str, object]) -> list[object]:
    turns = raw.get("turns", [])
    if not isinstance(turns, list):
        raise ScriptError("script.turns: expected a list")
    return turns


def check_script_keys(raw: object, known: frozenset[str]) -> Mapping[str, object] | None:
    """The top-level mapping (None for an empty file); unknown keys are an error."""
    if raw is None:
        return None
    if not isinstance(raw, Mapping):
        raise ScriptError("script: expected a mapping at the top level")
    unknown = set(raw) - known
    if unknown:
        raise ScriptError(f"script: unknown key(s) {sorted(unknown)}; known: {sorted(known)}")
    return raw


def parse_script(
    raw: object,
    *,
    script: Callable[..., ScriptT],
    turn: Callable[..., TurnT],
    scalars: Mapping[str, type],
    turn_faults: tuple[str, ...],
) -> ScriptT:
    """A vendor's `script(turns=..., default_reply=..., rejected_api_keys=..., known_models=...,
    **scalars)` from the top-level mapping; each turn is `turn(reply=..., heard=..., **faults)`, a
    fault being an optional integer (milliseconds). Unknown keys and wrong types are errors."""
    mapping = check_script_keys(
        raw, frozenset({"turns", "default_reply", "rejected_api_keys", "known_models", *scalars})
    )
    if mapping is None:
        return script()
    values: dict[str, object] = {
        key: None if mapping[key] is None else typed(mapping[key], kind, f"script.{key}")
        for key, kind in scalars.items()
        if key in mapping
    }
    if "default_reply" in mapping:
        values["default_reply"] = parse_say(mapping["default_reply"], "script.default_reply")
    turn_keys = TURN_KEYS | set(turn_faults)

    def parse_turn(raw_turn: object, where: str) -> TurnT:
        fields = check_turn_keys(raw_turn, where, turn_keys)
        return turn(
            reply=parse_reply(fields, where),
            heard=typed(fields.get("heard", "hello robot"), str, f"{where}.heard"),
            **{key: optional_int(fields, key, where) for key in turn_faults},
        )

    try:
        return script(
            turns=tuple(parse_turn(item, f"script.turns[{i}]") for i, item in enumerate(turn_list(mapping))),
            rejected_api_keys=strings(mapping, "rejected_api_keys"),
            known_models=strings(mapping, "known_models"),
            **values,
        )
    except ScriptError:
        raise
    except (TypeError, ValueError) as error:
        raise ScriptError(f"script: {error}") from error


def load_yaml_script(path: Path, from_mapping: Callable[[object], T]) -> T:
    """Read a YAML script file and build it; every error names the file."""
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as error:
        raise ScriptError(f"{path}: not valid YAML: {error}") from error
    try:
        return from_mapping(raw)
    except ScriptError as error:
        raise ScriptError(f"{path}: {error}") from error
