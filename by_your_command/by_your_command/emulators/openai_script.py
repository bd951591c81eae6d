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

import math
from dataclasses import dataclass, field
from pathlib import Path

from by_your_command.emulators.script_common import (
    CallTool,
    Reply,
    Say,
    ScriptError,
    Silence,
    load_yaml_script,
    parse_script,
)

__all__ = ["CallTool", "Reply", "Say", "Script", "ScriptError", "Silence", "Turn", "load_script"]


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


# Top-level keys that set a `Script` field of the same name, with their types:
_SCALARS: dict[str, type] = {
    "default_heard": str,
    "pace": float,
    "ms_per_char": int,
    "delta_ms": int,
    "session_expiry_s": float,
    "image_tokens": int,
}
# Turn keys that set a fault field of `Turn` (milliseconds or none):
_TURN_FAULTS = ("stall_after_ms", "drop_after_ms")


def script_from_mapping(raw: object) -> Script:
    return parse_script(raw, script=Script, turn=Turn, scalars=_SCALARS, turn_faults=_TURN_FAULTS)


def load_script(path: Path) -> Script:
    """Read a YAML script (the format is in this module's docstring)."""
    return load_yaml_script(path, script_from_mapping)
