"""Tool mode: the `robot_command` function tool, whose result is the command processor's verdict.

A call publishes its command on `command_request` with a request id and waits (with a deadline) for
the `command_status` verdicts that echo that id (one per command in it), so the model learns
"refused: unknown preset" or "no answer from the robot" and can say so instead of pretending it moved.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field

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


@dataclass
class PendingCall:
    call_id: str
    request_id: str  # what the command processor echoes in each of this call's verdicts
    command: str
    deadline: float
    verdicts: dict[int, CommandStatus] = field(default_factory=dict)  # by their index

    def complete(self, count: int) -> bool:
        return len(self.verdicts) >= count


class PendingVerdicts:
    """Tool calls waiting for their verdicts, matched by the request id the command processor
    echoes (never by text: the same words from another source must not answer a call).

    A call is added before its command is routed (`routed` marks it sent to the robot): the runtime
    routes once the provider events queued behind it are handled, so a cancellation that came with
    the call withdraws a command the robot never saw. Only routed calls take verdicts.
    """

    def __init__(self) -> None:
        self._calls: dict[str, PendingCall] = {}  # by request id, oldest first
        self._unrouted: set[str] = set()

    def add(self, call_id: str, request_id: str, command: str, deadline: float) -> None:
        self._calls[request_id] = PendingCall(call_id, request_id, command, deadline)
        self._unrouted.add(request_id)

    def unrouted(self) -> list[PendingCall]:
        return [call for call in self._calls.values() if call.request_id in self._unrouted]

    def routed(self, request_id: str) -> None:
        self._unrouted.discard(request_id)

    def take(self, verdict: CommandStatus) -> tuple[PendingCall, list[CommandStatus]] | None:
        """Keep a verdict of a routed call; the call and all its verdicts in order once complete."""
        call = self._calls.get(verdict.request_id) if verdict.request_id else None
        if call is None or call.request_id in self._unrouted:
            return None
        if not 0 <= verdict.index < verdict.count:
            return None  # malformed: the call's deadline answers it
        call.verdicts[verdict.index] = verdict
        if not call.complete(verdict.count):
            return None
        del self._calls[call.request_id]
        return call, [call.verdicts[index] for index in sorted(call.verdicts)]

    def cancel(self, call_id: str) -> tuple[PendingCall, bool] | None:
        """Withdraw a call (the provider cancelled it): the call and whether its command had been
        routed; None if it is not waiting any more."""
        for call in self._calls.values():
            if call.call_id == call_id:
                routed = call.request_id not in self._unrouted
                self._remove(call)
                return call, routed
        return None

    def expired(self, now: float) -> list[PendingCall]:
        late = [call for call in self._calls.values() if call.deadline <= now]
        for call in late:
            self._remove(call)
        return late

    def next_deadline(self) -> float | None:
        return min((call.deadline for call in self._calls.values()), default=None)

    def _remove(self, call: PendingCall) -> None:
        del self._calls[call.request_id]
        self._unrouted.discard(call.request_id)

    def __len__(self) -> int:
        return len(self._calls)
