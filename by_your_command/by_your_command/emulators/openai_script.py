"""What the OpenAI Realtime emulator answers: a script of turns, plus pacing and faults.

Each `response.create` a client sends consumes the next turn (shared by every connection of one
emulator, so a conversation carries on when an agent rotates its session); when the script runs
out, `default_reply` answers. A tool-call turn's `then` reply answers the response the client
requests after sending the tool output.

YAML form (`byc emulate openai --script FILE`; every key optional):

    pace: 1.0                  # audio deltas paced at real time; 0.5 twice as fast; 0 no waiting
    ms_per_char: 60            # reply audio length per character of text
    session_expiry_s: 3600     # then error session_expired and close
    rejected_api_keys: [sk-revoked]   # HTTP 401 at the handshake
    known_models: [gpt-realtime-2.1]  # other models: responses fail with model_not_found
    default_reply: {say: Hello from the emulator.}
    turns:
      - {heard: hello robot, say: "Hi! What can I do?"} # user transcript, spoken reply
      - {text: Only text.}                              # a text reply even in an audio session
      - tool: {name: robot_command, arguments: {command: wave}}
        then: {say: I waved.}                           # the reply after the tool output
      - {silent: true}                                  # never answers until cancelled
      - {say: A long story..., stall_after_ms: 300}     # stops after 300 ms of audio
      - {say: A long story..., drop_after_ms: 300}      # drops the TCP connection there
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import yaml

Modality = Literal["auto", "audio", "text"]


@dataclass(frozen=True)
class Say:
    """The model's words. `modality` auto follows the session/response output modalities; `text`
    answers in text even in an audio session (a text-only reply)."""

    text: str
    modality: Modality = "auto"


@dataclass(frozen=True)
class CallTool:
    """A function call; `then` answers the next response (after the client sent the tool output)."""

    name: str
    arguments: str  # JSON text, as the model writes it
    then: Say = field(default_factory=lambda: Say("Done."))


@dataclass(frozen=True)
class Silence:
    """Never answer: the response starts and then nothing comes until the client cancels it."""


Reply = Say | CallTool | Silence


@dataclass(frozen=True)
class Turn:
    reply: Reply
    heard: str = "hello robot"  # transcript of the user audio committed before this turn
    # Faults (milliseconds of reply audio sent before they strike; None = off):
    stall_after_ms: int | None = None  # stop sending and wait, as a slow model would, until cancelled
    drop_after_ms: int | None = None  # close the TCP connection without a close frame

    def __post_init__(self) -> None:
        for fault_ms in (self.stall_after_ms, self.drop_after_ms):
            if fault_ms is not None and fault_ms < 0:
                raise ValueError(f"fault times must be >= 0 ms, got {fault_ms}")


@dataclass(frozen=True)
class Script:
    turns: tuple[Turn, ...] = ()
    default_reply: Say = field(default_factory=lambda: Say("Hello from the emulator."))
    default_heard: str = "hello robot"
    # Delay per audio delta = its duration x pace: 1 is real time, 0.5 twice as fast, 0 no waiting.
    pace: float = 0.0
    ms_per_char: int = 60  # reply audio length: about 16 characters a second, like speech
    delta_ms: int = 100  # audio per output_audio.delta
    session_expiry_s: float | None = None  # then error session_expired and close (real limit: 3600)
    rejected_api_keys: tuple[str, ...] = ()  # HTTP 401 at the handshake
    known_models: tuple[str, ...] = ()  # non-empty: other models fail every response (model_not_found)
    image_tokens: int = 85  # invented: billed per input_image in the conversation, each response

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pace) and self.pace >= 0):
            raise ValueError(f"pace must be a finite number >= 0, got {self.pace}")
        if self.ms_per_char < 1 or self.delta_ms < 10:
            raise ValueError("ms_per_char must be >= 1 and delta_ms >= 10")
        if self.session_expiry_s is not None and not self.session_expiry_s > 0:
            raise ValueError(f"session_expiry_s must be > 0, got {self.session_expiry_s}")


class ScriptError(ValueError):
    """A script file that does not describe a script; the message names the offending place."""


_TURN_KEYS = {"heard", "say", "text", "tool", "then", "silent", "stall_after_ms", "drop_after_ms"}
_SCRIPT_KEYS = {
    "turns",
    "default_reply",
    "default_heard",
    "pace",
    "ms_per_char",
    "delta_ms",
    "session_expiry_s",
    "rejected_api_keys",
    "known_models",
    "image_tokens",
}


def _str(value: object, where: str) -> str:
    if not isinstance(value, str):
        raise ScriptError(f"{where}: expected a string, got {type(value).__name__}")
    return value


def _int(value: object, where: str) -> int:
    if not isinstance(value, int) or isinstance(value, bool):
        raise ScriptError(f"{where}: expected an integer, got {type(value).__name__}")
    return value


def _float(value: object, where: str) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise ScriptError(f"{where}: expected a number, got {type(value).__name__}")
    return float(value)


def _optional_int(value: object, where: str) -> int | None:
    return None if value is None else _int(value, where)


def _say(value: object, where: str) -> Say:
    if isinstance(value, str):
        return Say(value)
    if isinstance(value, Mapping) and set(value) <= {"say", "text"} and len(value) == 1:
        key, text = next(iter(value.items()))
        return Say(_str(text, f"{where}.{key}"), "auto" if key == "say" else "text")
    raise ScriptError(f"{where}: expected a string or {{say: ...}} / {{text: ...}}")


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
    if "say" in raw:
        reply = Say(_str(raw["say"], f"{where}.say"))
    elif "text" in raw:
        reply = Say(_str(raw["text"], f"{where}.text"), "text")
    elif "silent" in raw:
        reply = Silence()
    else:
        tool = raw["tool"]
        if not isinstance(tool, Mapping) or set(tool) - {"name", "arguments"} or "name" not in tool:
            raise ScriptError(f"{where}.tool: expected {{name: ..., arguments: {{...}}}}")
        arguments = tool.get("arguments", {})
        text = arguments if isinstance(arguments, str) else json.dumps(arguments)
        then = _say(raw["then"], f"{where}.then") if "then" in raw else Say("Done.")
        reply = CallTool(_str(tool["name"], f"{where}.tool.name"), text, then)
    if "then" in raw and not isinstance(reply, CallTool):
        raise ScriptError(f"{where}: `then` only follows a tool call")
    return Turn(
        reply=reply,
        heard=_str(raw.get("heard", "hello robot"), f"{where}.heard"),
        stall_after_ms=_optional_int(raw.get("stall_after_ms"), f"{where}.stall_after_ms"),
        drop_after_ms=_optional_int(raw.get("drop_after_ms"), f"{where}.drop_after_ms"),
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
    defaults = Script()

    def strings(key: str) -> tuple[str, ...]:
        values = raw.get(key, [])
        if not isinstance(values, list):
            raise ScriptError(f"script.{key}: expected a list of strings")
        return tuple(_str(value, f"script.{key}[{i}]") for i, value in enumerate(values))

    expiry = raw.get("session_expiry_s")
    try:
        return Script(
            turns=tuple(_turn(turn, f"script.turns[{i}]") for i, turn in enumerate(turns)),
            default_reply=_say(raw["default_reply"], "script.default_reply")
            if "default_reply" in raw
            else defaults.default_reply,
            default_heard=_str(raw.get("default_heard", defaults.default_heard), "script.default_heard"),
            pace=_float(raw.get("pace", defaults.pace), "script.pace"),
            ms_per_char=_int(raw.get("ms_per_char", defaults.ms_per_char), "script.ms_per_char"),
            delta_ms=_int(raw.get("delta_ms", defaults.delta_ms), "script.delta_ms"),
            session_expiry_s=None if expiry is None else _float(expiry, "script.session_expiry_s"),
            rejected_api_keys=strings("rejected_api_keys"),
            known_models=strings("known_models"),
            image_tokens=_int(raw.get("image_tokens", defaults.image_tokens), "script.image_tokens"),
        )
    except ScriptError:
        raise
    except ValueError as error:
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
