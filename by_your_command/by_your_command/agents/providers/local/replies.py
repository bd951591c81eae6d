"""The offline agent's answer to a tool result: a robot_command verdict or a robot tool's outcome
(acknowledgements and question answers are in local_speech/replies.py).

A verdict comes back as the tool result the runtime wrote (agents/robot_tool.result_json), a robot
tool's outcome as `{"ok", "tool", "status", "result" | "error"}` (agents/robot_calls.call_result).
Both are read as untrusted text: parsed defensively, any text to be said cut to a bounded length
and stripped to speakable characters, so a refusal is never minutes of audio or espeak markup, and
only an explicit success is ever said as one.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

MAX_RESULT_CHARS = 4000  # a tool result is a small JSON object; longer is not parsed
MAX_REASON_CHARS = 120  # a refusal is spoken: a long reason would be minutes of audio
MAX_MESSAGE_CHARS = 160  # a service's own `message`, said as the reply to its success
DONE = "Done."
_UNSPEAKABLE = re.compile(r"[^A-Za-z0-9 ,.'!?:;()+-]+")
# The runtime's note for a robot action that ended after the session that called it
# (agents/runtime.LATE_RESULT_NOTE), sent as a text turn: its result JSON is the last {...}.
_LATE_NOTE = re.compile(
    r"^\(The robot reports: your earlier call [A-Za-z][A-Za-z0-9_]{0,63}\(.*\) ended: (\{.*\})\. "
    r"Tell the user briefly\.\)$",
    re.DOTALL,
)


@dataclass(frozen=True)
class Verdict:
    """A tool result as far as it could be read: the robot_command verdict, or a robot tool's
    outcome (accepted = ok)."""

    accepted: bool
    command: str
    reason: str
    message: str = ""  # a robot tool's result `message` (a service's own words), said when accepted


def parse_tool_result(output: str) -> Verdict:
    """The verdict in a tool result; anything unreadable is a refusal that says so."""
    if len(output) > MAX_RESULT_CHARS:
        return Verdict(False, "", "the robot's answer was too long to read")
    try:
        data = json.loads(output)
    except ValueError:
        return Verdict(False, "", "the robot's answer was unreadable")
    if not isinstance(data, dict):
        return Verdict(False, "", "the robot's answer was unreadable")
    if "ok" in data:  # a robot tool's outcome
        error = data.get("error")
        return Verdict(
            data.get("ok") is True,
            "",
            error if isinstance(error, str) else "",
            message=_message(data.get("result")),
        )
    accepted = data.get("accepted") is True
    command = data.get("command")
    reason = data.get("reason")
    return Verdict(
        accepted,
        command if isinstance(command, str) else "",
        reason if isinstance(reason, str) else "",
    )


def speakable(text: str, limit: int = MAX_REASON_CHARS) -> str:
    """Untrusted text made safe to speak: bounded, `@` read as a space, odd characters dropped."""
    text = _UNSPEAKABLE.sub(" ", text[: limit * 2].replace("@", " ").replace("_", " "))
    text = " ".join(text.split())
    return text[:limit].rstrip()


def refusal(template: str, reason: str) -> str:
    return template.format(reason=speakable(reason) or "no reason given")


def _message(result: object) -> str:
    """The `message` of a result that has one (std_srvs/Trigger and the like), speakable; "" else."""
    message = result.get("message") if isinstance(result, dict) else None
    return speakable(message, MAX_MESSAGE_CHARS) if isinstance(message, str) else ""


def success(message: str) -> str:
    """What a robot tool's success is said as: its own message, or "Done."."""
    if not message:
        return DONE
    return message if message[-1] in ".!?" else f"{message}."


def late_result(text: str) -> str | None:
    """The result JSON in the runtime's note of a call another session made, or None: the offline
    agent answers it as it answers its own calls' results (from the result alone)."""
    if len(text) > MAX_RESULT_CHARS + 500:
        return None
    match = _LATE_NOTE.match(text)
    return match.group(1) if match else None
