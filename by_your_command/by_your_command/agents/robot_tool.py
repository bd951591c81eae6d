"""Tool mode: the `robot_command` function tool, whose result is the command processor's verdict.

A call publishes its command on `command_request` with a request id and waits (with a deadline) for
the `command_status` verdicts that echo that id (one per command in it), so the model learns
"refused: unknown preset" or "no answer from the robot" and can say so instead of pretending it moved.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

from by_your_command.agents.inputs import CommandStatus
from by_your_command.agents.provider import ToolSpec

TOOL_NAME = "robot_command"
MAX_COMMAND_CHARS = 200

ROBOT_COMMAND_TOOL = ToolSpec(
    name=TOOL_NAME,
    description="Send one command from the robot's command reference (e.g. 'pan@left'). "
    "The result says whether the robot accepted it and why not.",
    parameters={
        "type": "object",
        "properties": {"command": {"type": "string", "description": "one command, e.g. lookup or pan@left"}},
        "required": ["command"],
        "additionalProperties": False,
    },
)


class BadToolCall(ValueError):
    """Arguments the model wrote that are not one usable command (told to the model as the result)."""


def parse_command(arguments: str) -> str:
    try:
        data = json.loads(arguments)
    except ValueError:
        raise BadToolCall("arguments are not JSON") from None
    command = data.get("command") if isinstance(data, dict) else None
    if not isinstance(command, str) or not command.strip():
        raise BadToolCall("missing 'command' (a non-empty string)")
    if len(command) > MAX_COMMAND_CHARS or "\n" in command:
        raise BadToolCall("'command' must be one line of at most 200 characters")
    return command.strip()


def result_json(accepted: bool, command: str, reason: str) -> str:
    return json.dumps({"accepted": accepted, "command": command, "reason": reason})


def verdicts_json(verdicts: Sequence[CommandStatus]) -> str:
    """The result of a call from all its verdicts: one command as before; several with each one's
    verdict too (accepted only if every command was)."""
    if len(verdicts) == 1:
        only = verdicts[0]
        return result_json(only.accepted, only.command or only.raw, only.reason)
    refused = [v for v in verdicts if not v.accepted]
    return json.dumps(
        {
            "accepted": not refused,
            "command": ", ".join(v.command or v.raw for v in verdicts),
            "reason": "; ".join(f"{v.command or v.raw}: {v.reason}" for v in refused),
            "commands": [
                {"command": v.command or v.raw, "accepted": v.accepted, "reason": v.reason} for v in verdicts
            ],
        }
    )
