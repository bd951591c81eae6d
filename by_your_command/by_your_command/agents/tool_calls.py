"""A tool call of the model: which tool it is and whether the robot's rules let it run now
(decided here), then its verdicts and results (kept here until the model is sent them). The runtime
owns these and does the sending.

- `decide`: the robot's own tool (tool mode), `robot_command` (its command, for the processor), or
  a refusal the model is told as the result.
- `refusal`: a robot tool's rules now (asleep, too soon, too many running, a yes not heard).
- `PendingVerdicts`: `robot_command` calls waiting for the command processor's verdicts.
- `ResponseResults`: results held per response, sent together once all are in.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field

from by_your_command.agents.events import ToolCall
from by_your_command.agents.inputs import Attention, CommandStatus
from by_your_command.agents.provider import ToolResult, ToolSpec
from by_your_command.agents.robot_calls import MAX_ACTIVE_CALLS, RobotCalls
from by_your_command.agents.robot_tool import TOOL_NAME, BadToolCall, parse_command, result_json
from by_your_command.tools.catalog import Catalog, RobotTool

# Words that are positive evidence of a spoken yes (a call that needs confirming needs one).
YES_WORDS = frozenset(
    ("yes", "yeah", "yep", "sure", "ok", "okay", "confirm", "confirmed", "go", "ahead", "please", "correct")
)


@dataclass(frozen=True)
class RunRobotTool:
    tool: RobotTool


@dataclass(frozen=True)
class RouteCommand:
    command: str  # for the command processor (its verdict is the result)


@dataclass(frozen=True)
class Refuse:
    output: str  # the result the model is told


def decide(call: ToolCall, tool_mode: bool, catalog: Catalog) -> RunRobotTool | RouteCommand | Refuse:
    """What a tool call is. Only a tool-mode agent has tools; the robot's own come first."""
    robot_tool = catalog.get(call.name) if tool_mode else None
    if robot_tool is not None:
        return RunRobotTool(robot_tool)
    if not tool_mode or call.name != TOOL_NAME:
        return Refuse(result_json(False, "", f"no tool named {call.name!r}"))
    try:
        return RouteCommand(parse_command(call.arguments))
    except BadToolCall as error:
        return Refuse(result_json(False, "", str(error)))


def refusal(
    tool: RobotTool, arguments: str, attention: Attention, calls: RobotCalls, last_user_text: str, now: float
) -> str:
    """Why the robot tool's rules refuse this call now ("" if they do not): nothing is sent then."""
    if attention is not Attention.AWAKE and not tool.rules.while_asleep:
        return f"the robot is {attention.value}: {tool.name} waits until it is woken"
    wait = calls.too_soon(tool, now)
    if wait > 0:
        return f"called too soon: {tool.name} may run again in {wait:.1f} s"
    if tool.kind != "command" and len(calls) >= MAX_ACTIVE_CALLS:
        return f"the robot is already doing {MAX_ACTIVE_CALLS} things: stop one first"
    if tool.rules.confirm and not (confirmed(arguments) and sounds_like_yes(last_user_text)):
        return "this needs the user's spoken yes first: ask them, then call again with confirmed: true"
    return ""


def confirmed(arguments: str) -> bool:
    try:
        return json.loads(arguments).get("confirmed") is True
    except (ValueError, AttributeError):
        return False


def sounds_like_yes(text: str) -> bool:
    """Positive evidence for a confirmation: the user's last words hold a yes."""
    return any(word in YES_WORDS for word in re.findall(r"[a-z]+", text.lower()))


def robot_tool_spec(tool: RobotTool) -> ToolSpec:
    """A robot tool as the model is offered it (with its spoken phrases, for delegation)."""
    spoken = tuple((phrase, json.dumps(arguments)) for phrase, arguments in tool.spoken_forms())
    return ToolSpec(tool.name, tool.description, tool.parameters, tool.kind == "action", spoken)


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
