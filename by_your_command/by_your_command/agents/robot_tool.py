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
from by_your_command.agents.provider import ToolResult, ToolSpec

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


@dataclass
class _ResponseCalls:
    session: int  # the provider session whose response made the calls (only it can take the results)
    turn: int  # the turn it answered (0: none): results of a turn that is over make a turn of their own
    call_ids: list[str] = field(default_factory=list)
    results: dict[str, str] = field(default_factory=dict)
    done: bool = False  # the response ended: no more calls will come in it


class ResponseResults:
    """Tool results held per response until the response is done and each of its calls is
    answered (or withdrawn), then sent together: the model is asked for one reply, not one per
    call. Bad calls and unknown tools are answered here too, so their response waits the same."""

    def __init__(self) -> None:
        self._responses: dict[str, _ResponseCalls] = {}

    def expect(self, session: int, response_id: str, call_id: str, turn: int = 0) -> None:
        self._responses.setdefault(response_id, _ResponseCalls(session, turn)).call_ids.append(call_id)

    def calls_of(self, response_id: str) -> list[str]:
        calls = self._responses.get(response_id)
        return list(calls.call_ids) if calls is not None else []

    def answer(self, call_id: str, output: str) -> None:
        for calls in self._responses.values():
            if call_id in calls.call_ids:
                calls.results[call_id] = output

    def withdraw(self, call_id: str) -> None:
        for calls in self._responses.values():
            if call_id in calls.call_ids:
                calls.call_ids.remove(call_id)
                calls.results.pop(call_id, None)

    def response_done(self, response_id: str) -> None:
        calls = self._responses.get(response_id)
        if calls is not None:
            calls.done = True

    def take_ready(self) -> list[tuple[int, int, tuple[ToolResult, ...]]]:
        """(session, turn, results) of every response now complete, in the order the calls came;
        a response whose calls were all withdrawn has nothing to send and is dropped."""
        ready = [
            (response_id, calls)
            for response_id, calls in self._responses.items()
            if calls.done and all(call_id in calls.results for call_id in calls.call_ids)
        ]
        for response_id, _ in ready:
            del self._responses[response_id]
        return [
            (calls.session, calls.turn, tuple(ToolResult(c, calls.results[c]) for c in calls.call_ids))
            for _, calls in ready
            if calls.call_ids
        ]

    def clear(self) -> None:
        self._responses.clear()

    def __len__(self) -> int:
        return len(self._responses)
