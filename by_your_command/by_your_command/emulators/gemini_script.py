"""What the Gemini Live emulator answers: a script of turns, plus pacing, limits and faults.

Each user turn (activityEnd, clientContent with turnComplete, realtimeInput text) consumes the next
scripted turn; the turns are shared by every connection of one emulator, so a conversation carries
on across goAway, resumption and rotation. When the script runs out, `default_reply` answers. A
tool turn's `then` answers once the client sent the toolResponse; a user turn (or activityStart)
while calls wait for their toolResponse cancels them (toolCallCancellation, then turnComplete), as
the real server does when interrupted.

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
      - tool: {name: robot_command, arguments: {command: wave}}
        cancel_after_ms: 200                   # toolCallCancellation if no toolResponse by then
      - {silent: true}                         # never answers until interrupted
      - {say: A long story..., stall_after_ms: 300}   # stops after 300 ms of audio
      - {say: A long story..., drop_after_ms: 300}    # drops the TCP connection there
      - {say: A long story..., close_after_ms: 300}   # closes 1011 "Deadline expired" there
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

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

FrameModality = Literal["IMAGE", "VIDEO"]


@dataclass(frozen=True)
class Turn:
    reply: Reply
    heard: str = "hello robot"  # input transcription of the user's audio
    # Faults, in milliseconds of reply audio sent before they strike (None = off):
    stall_after_ms: int | None = None  # stop sending until interrupted
    drop_after_ms: int | None = None  # close the TCP connection without a close frame
    close_after_ms: int | None = None  # close 1011 "Deadline expired"
    # A tool turn: toolCallCancellation this long after the toolCall when no toolResponse came
    # (invented: the real server cancels only when the client interrupts)
    cancel_after_ms: int | None = None

    def __post_init__(self) -> None:
        for fault_ms in (self.stall_after_ms, self.drop_after_ms, self.close_after_ms, self.cancel_after_ms):
            if fault_ms is not None and fault_ms < 0:
                raise ValueError(f"fault times must be >= 0 ms, got {fault_ms}")
        if self.cancel_after_ms is not None and not isinstance(self.reply, CallTool):
            raise ValueError("cancel_after_ms needs a tool turn")


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


# Top-level keys that set a `Script` field of the same name, with their types:
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
# Turn keys that set a fault field of `Turn` (milliseconds or none):
_TURN_FAULTS = ("stall_after_ms", "drop_after_ms", "close_after_ms", "cancel_after_ms")


def script_from_mapping(raw: object) -> Script:
    return parse_script(raw, script=Script, turn=Turn, scalars=_SCALARS, turn_faults=_TURN_FAULTS)


def load_script(path: Path) -> Script:
    """Read a YAML script (the format is in this module's docstring)."""
    return load_yaml_script(path, script_from_mapping)
