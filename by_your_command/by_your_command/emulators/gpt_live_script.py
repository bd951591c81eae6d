"""What the GPT-Live emulator says: a script of turns, plus pacing, the speech detector and faults.

The model decides turn-taking: each time the emulator hears the user finish speaking (energy
based: `min_speech_ms` of audio above `speech_rms`, then `end_silence_ms` below it) it takes the
next turn, shared by every connection of one emulator (a conversation carries on when an agent
opens a new session). A turn with `after_ms` also starts by itself once the session has been idle
that long (no reply, no speech): the model speaking first. When the script runs out,
`default_reply` answers.

A `delegate` turn hands work to the client (`session.delegation.created`); `acknowledge` is spoken
meanwhile. The client answers with `session.commentary.append` naming the delegation; then `then`
is spoken, or without `then` the commentary's own words (the model speaks the result it is given).

YAML form (`byc emulate gpt-live --script FILE`; every key optional):

    pace: 1.0                  # reply audio paced at real time; 0.5 twice as fast; 0 no waiting
    ms_per_char: 60            # reply audio length per character of text
    speech_rms: 500            # int16 RMS above which input audio counts as speech
    min_speech_ms: 300         # speech needed to start a user turn (and to interrupt a reply)
    end_silence_ms: 500        # quiet that ends it
    usage_interval_ms: 1000    # session.usage.updated cadence
    session_expiry_s: 3600     # then session.closed (reason expired) and close
    rejected_api_keys: [sk-revoked]   # HTTP 401 at the handshake
    known_models: [gpt-live-1]        # other models: session.start refused (model_not_found)
    default_reply: Hello from the emulator.
    turns:
      - {heard: hello robot, say: "Hi! What can I do?"}  # user transcript, spoken reply
      - heard: please wave
        delegate: {acknowledge: "Sure, one moment."}   # or `delegate: true`
        then: I waved.                                 # after the client's commentary for it
      - {say: "A long story...", interruptible: false} # talks on through user speech
      - {say: "Still there?", after_ms: 5000}          # unprompted after 5 s of idle
      - {silent: true}                                 # hears the user and says nothing
      - {say: "A long story...", drop_after_ms: 300}   # drops the TCP connection there
      - {say: "A long story...", close_after_ms: 300}  # session.closed (reason content) there
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from by_your_command.emulators.script_common import (
    Say,
    ScriptError,
    Silence,
    check_script_keys,
    check_turn_keys,
    load_yaml_script,
    optional_int,
    strings,
    turn_list,
    typed,
)

__all__ = ["Delegate", "Reply", "Say", "Script", "ScriptError", "Silence", "Turn", "load_script"]


@dataclass(frozen=True)
class Delegate:
    """Work handed to the client. `acknowledge` is spoken while it runs (None: nothing); `then`
    answers the client's commentary for it (None: the commentary's own words)."""

    acknowledge: Say | None = None
    then: Say | None = None


Reply = Say | Delegate | Silence


@dataclass(frozen=True)
class Turn:
    reply: Reply
    heard: str = "hello robot"  # transcript of the user speech this turn answers
    interruptible: bool = True  # False: user speech does not stop it (the model talks on)
    after_ms: int | None = None  # also starts by itself after this much idle time
    # Faults (milliseconds of reply audio sent before they strike; None = off):
    drop_after_ms: int | None = None  # close the TCP connection without a close frame
    close_after_ms: int | None = None  # session.closed (reason content), then a normal close

    def __post_init__(self) -> None:
        for value in (self.after_ms, self.drop_after_ms, self.close_after_ms):
            if value is not None and value < 0:
                raise ValueError(f"turn times must be >= 0 ms, got {value}")


@dataclass(frozen=True)
class Script:
    turns: tuple[Turn, ...] = ()
    default_reply: Say = field(default_factory=lambda: Say("Hello from the emulator."))
    default_heard: str = "hello robot"
    pace: float = 1.0  # delay per audio delta = its duration x pace (0: no waiting)
    ms_per_char: int = 60  # reply audio length: about 16 characters a second, like speech
    delta_ms: int = 100  # audio per session.output_audio.delta
    speech_rms: float = 500.0
    min_speech_ms: int = 300
    end_silence_ms: int = 500
    usage_interval_ms: int = 1000
    session_expiry_s: float | None = None
    rejected_api_keys: tuple[str, ...] = ()
    known_models: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pace) and self.pace >= 0):
            raise ValueError(f"pace must be a finite number >= 0, got {self.pace}")
        if self.ms_per_char < 1 or self.delta_ms < 10:
            raise ValueError("ms_per_char must be >= 1 and delta_ms >= 10")
        if not (math.isfinite(self.speech_rms) and self.speech_rms > 0):
            raise ValueError(f"speech_rms must be > 0, got {self.speech_rms}")
        if self.min_speech_ms < 10 or self.end_silence_ms < 10 or self.usage_interval_ms < 10:
            raise ValueError("min_speech_ms, end_silence_ms and usage_interval_ms must be >= 10")
        if self.session_expiry_s is not None and not self.session_expiry_s > 0:
            raise ValueError(f"session_expiry_s must be > 0, got {self.session_expiry_s}")


_SCALARS: dict[str, type] = {
    "default_heard": str,
    "pace": float,
    "ms_per_char": int,
    "delta_ms": int,
    "speech_rms": float,
    "min_speech_ms": int,
    "end_silence_ms": int,
    "usage_interval_ms": int,
    "session_expiry_s": float,
}
_TURN_KEYS = frozenset(
    {
        "heard",
        "say",
        "silent",
        "delegate",
        "then",
        "interruptible",
        "after_ms",
        "drop_after_ms",
        "close_after_ms",
    }
)
_SCRIPT_KEYS = frozenset({"turns", "default_reply", "rejected_api_keys", "known_models", *_SCALARS})


def _say(value: object, where: str) -> Say:
    return Say(typed(value, str, where))


def _reply(raw: Mapping[str, object], where: str) -> Reply:
    kinds = [key for key in ("say", "silent", "delegate") if key in raw]
    if len(kinds) != 1:
        raise ScriptError(f"{where}: give exactly one of say, silent, delegate (got {kinds})")
    if "then" in raw and kinds[0] != "delegate":
        raise ScriptError(f"{where}: `then` only follows a delegation")
    if kinds[0] == "say":
        return _say(raw["say"], f"{where}.say")
    if kinds[0] == "silent":
        return Silence()
    spec = raw["delegate"]
    if spec is True or spec is None:
        spec = {}
    if not isinstance(spec, Mapping) or set(spec) - {"acknowledge"}:
        raise ScriptError(f"{where}.delegate: expected true or {{acknowledge: ...}}")
    acknowledge = spec.get("acknowledge")
    return Delegate(
        None if acknowledge is None else _say(acknowledge, f"{where}.delegate.acknowledge"),
        _say(raw["then"], f"{where}.then") if "then" in raw else None,
    )


def _turn(raw: object, where: str) -> Turn:
    fields = check_turn_keys(raw, where, _TURN_KEYS)
    return Turn(
        reply=_reply(fields, where),
        heard=typed(fields.get("heard", "hello robot"), str, f"{where}.heard"),
        interruptible=typed(fields.get("interruptible", True), bool, f"{where}.interruptible"),
        after_ms=optional_int(fields, "after_ms", where),
        drop_after_ms=optional_int(fields, "drop_after_ms", where),
        close_after_ms=optional_int(fields, "close_after_ms", where),
    )


def script_from_mapping(raw: object) -> Script:
    mapping = check_script_keys(raw, _SCRIPT_KEYS)
    if mapping is None:
        return Script()
    values: dict[str, object] = {
        key: None if mapping[key] is None else typed(mapping[key], kind, f"script.{key}")
        for key, kind in _SCALARS.items()
        if key in mapping
    }
    if "default_reply" in mapping:
        values["default_reply"] = _say(mapping["default_reply"], "script.default_reply")
    try:
        return Script(
            turns=tuple(_turn(item, f"script.turns[{i}]") for i, item in enumerate(turn_list(mapping))),
            rejected_api_keys=strings(mapping, "rejected_api_keys"),
            known_models=strings(mapping, "known_models"),
            **values,  # type: ignore[arg-type]
        )
    except ScriptError:
        raise
    except (TypeError, ValueError) as error:
        raise ScriptError(f"script: {error}") from error


def load_script(path: Path) -> Script:
    """Read a YAML script (the format is in this module's docstring)."""
    return load_yaml_script(path, script_from_mapping)
