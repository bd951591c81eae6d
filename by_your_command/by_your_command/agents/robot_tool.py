"""Tool mode: the `robot_command` function tool, whose result is the command processor's verdict.

A call publishes its command on `response_cmd` and waits (with a deadline) for the `command_status`
verdict whose `raw` text matches, so the model learns "refused: unknown preset" or "no answer from
the robot" and can say so instead of pretending it moved.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

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


def _key(text: str) -> str:
    return " ".join(text.lower().split())


@dataclass(frozen=True)
class PendingCall:
    call_id: str
    command: str
    deadline: float


class PendingVerdicts:
    """Tool calls waiting for their verdict, matched by the command's text (oldest first).

    A call is added before its command is routed (`routed` marks it sent to the robot): the runtime
    routes once the provider events queued behind the call are handled, so a cancellation that
    came with the call withdraws a command the robot never saw. Only routed calls match verdicts.
    """

    def __init__(self) -> None:
        self._calls: list[PendingCall] = []
        self._unrouted: set[str] = set()

    def add(self, call_id: str, command: str, deadline: float) -> None:
        self._calls.append(PendingCall(call_id, command, deadline))
        self._unrouted.add(call_id)

    def unrouted(self) -> list[PendingCall]:
        return [call for call in self._calls if call.call_id in self._unrouted]

    def routed(self, call_id: str) -> None:
        self._unrouted.discard(call_id)

    def match(self, verdict: CommandStatus) -> PendingCall | None:
        for call in self._calls:
            if call.call_id not in self._unrouted and _key(call.command) == _key(verdict.raw):
                self._remove(call)
                return call
        return None

    def cancel(self, call_id: str) -> tuple[PendingCall, bool] | None:
        """Withdraw a call (the provider cancelled it): the call and whether its command had been
        routed; None if it is not waiting any more."""
        for call in self._calls:
            if call.call_id == call_id:
                routed = call_id not in self._unrouted
                self._remove(call)
                return call, routed
        return None

    def expired(self, now: float) -> list[PendingCall]:
        late = [call for call in self._calls if call.deadline <= now]
        for call in late:
            self._remove(call)
        return late

    def next_deadline(self) -> float | None:
        return min((call.deadline for call in self._calls), default=None)

    def _remove(self, call: PendingCall) -> None:
        self._calls.remove(call)
        self._unrouted.discard(call.call_id)

    def __len__(self) -> int:
        return len(self._calls)
