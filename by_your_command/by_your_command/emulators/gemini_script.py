"""What the Gemini Live emulator answers: a script of turns, plus pacing, limits and faults.

Each user turn (activityEnd, clientContent with turnComplete, realtimeInput text) consumes the next
scripted turn; the turns are shared by every connection of one emulator, so a conversation carries
on across goAway, resumption and rotation. When the script runs out, `default_reply` answers. A
tool turn's `then` answers once the client sent the toolResponse.

YAML form (`byc emulate gemini --script FILE`; every key optional):

    pace: 1.0                    # reply audio paced at real time; 0 = no waiting
    ms_per_char: 60              # reply audio length per character
    chunk_ms: 100                # audio per modelTurn message
    rejected_api_keys: [bad-key] # close 1007 "API key not valid" after the setup
    known_models: [gemini-3.8-live]   # other models: close 1008 (not found)
    handle_ttl_s: 7200           # resumption handles expire (the real server: 2 h)
    go_away_after_turns: 3       # goAway after the 3rd model turn of a connection
    go_away_time_left_s: 5       # ... announcing this much time, then close 1000
    deadline_s: 3480             # close 1011 "Deadline expired" (the 58-minute close)
    refuse_resume: false         # every resumption fails with 1007
    image_tokens: 258            # invented: tokens per camera frame in the context
    frame_modality: IMAGE        # how frames are reported in usage: IMAGE or VIDEO
    default_reply: {say: Hello from the Gemini emulator.}
    turns:
      - {heard: hello robot, say: "Hi! What can I do?"}
      - {text: Only text.}                     # text parts even in an audio session
      - tool: {name: robot_command, arguments: {command: wave}}
        then: {say: I waved.}
      - {silent: true}                         # never answers until interrupted
      - {say: A long story..., stall_after_ms: 300}   # stops after 300 ms of audio
      - {say: A long story..., drop_after_ms: 300}    # drops the TCP connection there
      - {say: A long story..., close_after_ms: 300}   # closes 1011 "Deadline expired" there
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

Modality = Literal["auto", "audio", "text"]
FrameModality = Literal["IMAGE", "VIDEO"]


@dataclass(frozen=True)
class Say:
    """The model's words. `modality` auto follows the session's responseModalities; `text` sends
    text parts even in an audio session."""

    text: str
    modality: Modality = "auto"


@dataclass(frozen=True)
class CallTool:
    name: str
    arguments: str  # a JSON object, as text
    then: Say = field(default_factory=lambda: Say("Done."))


@dataclass(frozen=True)
class Silence:
    """The model never answers (until the client interrupts)."""


Reply = Say | CallTool | Silence


@dataclass(frozen=True)
class Turn:
    reply: Reply
    heard: str = "hello robot"  # input transcription of the user's audio
    # Faults, in milliseconds of reply audio sent before they strike (None = off):
    stall_after_ms: int | None = None  # stop sending until interrupted
    drop_after_ms: int | None = None  # close the TCP connection without a close frame
    close_after_ms: int | None = None  # close 1011 "Deadline expired"

    def __post_init__(self) -> None:
        for fault_ms in (self.stall_after_ms, self.drop_after_ms, self.close_after_ms):
            if fault_ms is not None and fault_ms < 0:
                raise ValueError(f"fault times must be >= 0 ms, got {fault_ms}")


@dataclass(frozen=True)
class Script:
    turns: tuple[Turn, ...] = ()
    default_reply: Say = field(default_factory=lambda: Say("Hello from the Gemini emulator."))
    default_heard: str = "hello robot"
    pace: float = 0.0  # delay per audio chunk = its duration x pace
    ms_per_char: int = 60
    chunk_ms: int = 100
    rejected_api_keys: tuple[str, ...] = ()
    known_models: tuple[str, ...] = ()  # non-empty: other models are refused (1008)
    handle_ttl_s: float = 7200.0
    go_away_after_turns: int | None = None
    go_away_time_left_s: float = 5.0
    deadline_s: float | None = None
    refuse_resume: bool = False
    image_tokens: int = 258
    frame_modality: FrameModality = "IMAGE"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pace) and self.pace >= 0):
            raise ValueError(f"pace must be a finite number >= 0, got {self.pace}")
        if self.ms_per_char < 1 or self.chunk_ms < 10:
            raise ValueError("ms_per_char must be >= 1 and chunk_ms >= 10")
        if not self.handle_ttl_s > 0 or self.go_away_time_left_s < 0:
            raise ValueError("handle_ttl_s must be > 0 and go_away_time_left_s >= 0")
        if self.go_away_after_turns is not None and self.go_away_after_turns < 1:
            raise ValueError("go_away_after_turns must be >= 1")
        if self.deadline_s is not None and not self.deadline_s > 0:
            raise ValueError(f"deadline_s must be > 0, got {self.deadline_s}")
        if self.frame_modality not in ("IMAGE", "VIDEO") or self.image_tokens < 0:
            raise ValueError("frame_modality must be IMAGE or VIDEO, image_tokens >= 0")


class ScriptError(ValueError):
    """A script file that does not describe a script; the message names the offending place."""


_TURN_KEYS = {
    "heard",
    "say",
    "text",
    "tool",
    "then",
    "silent",
    "stall_after_ms",
    "drop_after_ms",
    "close_after_ms",
}
_SCALARS: dict[str, type] = {
    "default_heard": str,
    "pace": float,
    "ms_per_char": int,
    "chunk_ms": int,
    "handle_ttl_s": float,
    "go_away_after_turns": int,
    "go_away_time_left_s": float,
    "deadline_s": float,
    "refuse_resume": bool,
    "image_tokens": int,
    "frame_modality": str,
}
_SCRIPT_KEYS = {"turns", "default_reply", "rejected_api_keys", "known_models", *_SCALARS}


def _typed(value: object, kind: type, where: str) -> object:
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if kind is int and isinstance(value, bool):
        raise ScriptError(f"{where}: expected an integer")
    if not isinstance(value, kind):
        raise ScriptError(f"{where}: expected {kind.__name__}, got {type(value).__name__}")
    return value


def _say(value: object, where: str) -> Say:
    if isinstance(value, str):
        return Say(value)
    if isinstance(value, Mapping) and len(value) == 1 and set(value) <= {"say", "text"}:
        key, text = next(iter(value.items()))
        return Say(str(_typed(text, str, f"{where}.{key}")), "auto" if key == "say" else "text")
    raise ScriptError(f"{where}: expected a string or {{say: ...}} / {{text: ...}}")


def _optional_ms(raw: Mapping[str, object], key: str, where: str) -> int | None:
    value = raw.get(key)
    return None if value is None else int(_typed(value, int, f"{where}.{key}"))  # type: ignore[call-overload]


def _turn(raw: object, where: str) -> Turn:
    if not isinstance(raw, Mapping):
        raise ScriptError(f"{where}: expected a mapping")
    unknown = set(raw) - _TURN_KEYS
    if unknown:
        raise ScriptError(f"{where}: unknown key(s) {sorted(unknown)}; known: {sorted(_TURN_KEYS)}")
    kinds = [key for key in ("say", "text", "tool", "silent") if key in raw]
    if len(kinds) != 1:
        raise ScriptError(f"{where}: give exactly one of say, text, tool, silent (got {kinds})")
    reply: Reply
    if "say" in raw or "text" in raw:
        reply = _say({kinds[0]: raw[kinds[0]]}, where)
    elif "silent" in raw:
        reply = Silence()
    else:
        tool = raw["tool"]
        if not isinstance(tool, Mapping) or set(tool) - {"name", "arguments"} or "name" not in tool:
            raise ScriptError(f"{where}.tool: expected {{name: ..., arguments: {{...}}}}")
        arguments = tool.get("arguments", {})
        if not isinstance(arguments, Mapping):
            raise ScriptError(f"{where}.tool.arguments: expected a mapping")
        then = _say(raw["then"], f"{where}.then") if "then" in raw else Say("Done.")
        reply = CallTool(
            str(_typed(tool["name"], str, f"{where}.tool.name")), json.dumps(dict(arguments)), then
        )
    if "then" in raw and not isinstance(reply, CallTool):
        raise ScriptError(f"{where}: `then` only follows a tool call")
    return Turn(
        reply=reply,
        heard=str(_typed(raw.get("heard", "hello robot"), str, f"{where}.heard")),
        stall_after_ms=_optional_ms(raw, "stall_after_ms", where),
        drop_after_ms=_optional_ms(raw, "drop_after_ms", where),
        close_after_ms=_optional_ms(raw, "close_after_ms", where),
    )


def script_from_mapping(raw: object) -> Script:
    if raw is None:
        return Script()
    if not isinstance(raw, Mapping):
        raise ScriptError("script: expected a mapping at the top level")
    unknown = set(raw) - _SCRIPT_KEYS
    if unknown:
        raise ScriptError(f"script: unknown key(s) {sorted(unknown)}; known: {sorted(_SCRIPT_KEYS)}")
    turns = raw.get("turns", [])
    if not isinstance(turns, list):
        raise ScriptError("script.turns: expected a list")
    values: dict[str, Any] = {
        key: None if raw[key] is None else _typed(raw[key], kind, f"script.{key}")
        for key, kind in _SCALARS.items()
        if key in raw
    }
    for key in ("rejected_api_keys", "known_models"):
        listed = raw.get(key, [])
        if not isinstance(listed, list):
            raise ScriptError(f"script.{key}: expected a list of strings")
        values[key] = tuple(str(_typed(item, str, f"script.{key}[{i}]")) for i, item in enumerate(listed))
    if "default_reply" in raw:
        values["default_reply"] = _say(raw["default_reply"], "script.default_reply")
    try:
        return Script(
            turns=tuple(_turn(turn, f"script.turns[{i}]") for i, turn in enumerate(turns)), **values
        )
    except ScriptError:
        raise
    except (TypeError, ValueError) as error:
        raise ScriptError(f"script: {error}") from error


def load_script(path: Path) -> Script:
    """Read a YAML script (the format is in this module's docstring)."""
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as error:
        raise ScriptError(f"{path}: not valid YAML: {error}") from error
    try:
        return script_from_mapping(raw)
    except ScriptError as error:
        raise ScriptError(f"{path}: {error}") from error
