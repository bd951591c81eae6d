"""The offline agent's answer to a robot_command verdict (acknowledgements and question answers
are in offline/replies.py).

The verdict comes back as the tool result the runtime wrote (agents/robot_tool.result_json), but it
is read as untrusted text: parsed defensively, its reason cut to a bounded length and stripped to
speakable characters, so a refusal is never minutes of audio or espeak markup.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass

MAX_RESULT_CHARS = 4000  # a tool result is a small JSON object; longer is not parsed
MAX_REASON_CHARS = 120  # a refusal is spoken: a long reason would be minutes of audio
_UNSPEAKABLE = re.compile(r"[^A-Za-z0-9 ,.'!?:;()+-]+")


@dataclass(frozen=True)
class Verdict:
    """The robot_command tool result (agents/robot_tool.result_json), as far as it could be read."""

    accepted: bool
    command: str
    reason: str


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
