"""The robot's own tools run through the bridge (docs/tools.md): a call started (or refused), its
request sent, its progress told to the model, its cancel, and its end answered — to the session
that made it, or as a note once that session is gone.

`RobotCalls` (agents/robot_calls.py) keeps the calls in flight and decides; this sends what it
decides. The runtime owns both and calls these from its one task, so the state still changes only
there; what this needs of the runtime is handed in explicitly (no back-reference).
"""

from __future__ import annotations

import json
import logging
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from functools import partial

from by_your_command.agents.clock import Clock
from by_your_command.agents.events import ToolCall
from by_your_command.agents.inputs import Attention, CallFeedback, CallReplied
from by_your_command.agents.metrics import ToolCallMetrics
from by_your_command.agents.port import RobotPort
from by_your_command.agents.robot_calls import REPLY_GRACE_S, RobotCall, RobotCalls, call_result
from by_your_command.agents.session import SendToolProgress, Session
from by_your_command.agents.tool_calls import PendingVerdicts, refusal
from by_your_command.tools.catalog import RobotTool, ToolArgumentError

log = logging.getLogger(__name__)

# What the model reads when a robot action it started ends after its session did (or the call was
# withdrawn): the call itself is gone, so the result comes as a note, and the model tells the user.
LATE_RESULT_NOTE = (
    "(The robot reports: your earlier call {tool}({arguments}) ended: {result}. Tell the user briefly.)"
)
RECENT_ACTION_RESPONSES = 64  # responses that started actions, remembered (bounded)

Publish = Callable[[str, Callable[[], Awaitable[None]]], None]


@dataclass(frozen=True)
class SendFailed:
    """A robot tool's request could not be sent to the bridge (posted back to the scheduler)."""

    request_id: str
    error: str


class RobotToolRunner:
    def __init__(
        self,
        agent_id: str,
        calls: RobotCalls,
        verdicts: PendingVerdicts,
        verdict_timeout_s: float,
        port: RobotPort,
        clock: Clock,
        *,
        new_request_id: Callable[[], str],
        publish: Publish,
        post: Callable[[SendFailed], None],
        deliver: Callable[[str, str], None],
        tell_late: Callable[[str], None],
        session: Callable[[], Session | None],
    ) -> None:
        """`publish` sends off the scheduler (the outbox); `post` queues an item for the scheduler;
        `deliver(call_id, output)` answers a call; `tell_late(note)` gives the model a result its
        call can no longer take; `session()` is the provider session now (None: none open)."""
        self._agent_id = agent_id
        self._calls = calls
        self._verdicts = verdicts
        self._verdict_timeout_s = verdict_timeout_s
        self._port = port
        self._clock = clock
        self._new_request_id = new_request_id
        self._publish = publish
        self._post = post
        self._deliver = deliver
        self._tell_late = tell_late
        self._session = session
        self._action_responses: deque[str] = deque(maxlen=RECENT_ACTION_RESPONSES)

    def started_action(self, response_id: str) -> bool:
        """Whether this response started an action (its results come after its turn)."""
        return response_id in self._action_responses

    def start(
        self, session_serial: int, tool: RobotTool, call: ToolCall, attention: Attention, last_user_text: str
    ) -> None:
        """Run the model's call of `tool`, or refuse it (nothing is sent to the robot then)."""
        now = self._clock.now()
        try:
            refused = refusal(tool, call.arguments, attention, self._calls, last_user_text, now)
            if not refused and tool.kind == "command":
                command = tool.command_text(call.arguments)
            elif not refused:
                message = tool.build(call.arguments)
        except ToolArgumentError as error:
            refused = f"bad arguments: {error}"
        if refused:
            self._calls.counters.refused += 1
            log.info("agent %s: %s refused: %s", self._agent_id, tool.name, refused)
            self._publish_call(tool, "", call.arguments, "refused", error=refused)
            self._deliver(call.call_id, call_result(tool.name, False, "refused", error=refused))
            return
        request_id = self._new_request_id()
        if tool.kind == "command":  # the command processor's verdict answers it, like robot_command
            self._verdicts.add(call.call_id, request_id, command, now + self._verdict_timeout_s)
            return
        if tool.kind == "topic":
            send = partial(self._port.publish_tool_message, tool.ros_name, tool.type, message)
            self._send(request_id, send)
            self._publish_call(tool, request_id, call.arguments, "published")
            self._deliver(call.call_id, call_result(tool.name, True, "published", {}))
            return
        action = tool.kind == "action"
        limit = tool.rules.max_duration_s if action else tool.rules.timeout_s + REPLY_GRACE_S
        self._calls.start(
            RobotCall(call.call_id, session_serial, tool, request_id, call.arguments, now, now + limit)
        )
        log.info("agent %s: %s(%s) sent as %s", self._agent_id, tool.name, call.arguments[:200], request_id)
        if action:
            self._action_responses.append(call.response_id)
            send = partial(self._port.send_action_goal, request_id, tool.ros_name, tool.type, message)
        else:
            send = partial(self._port.call_service, request_id, tool.ros_name, tool.type, message)
        self._send(request_id, send)
        self._publish_call(tool, request_id, call.arguments, "running")

    def on_reply(self, item: CallReplied | CallFeedback | SendFailed) -> None:
        """The robot's answer to a call (feedback or its end), or a request that never left."""
        if isinstance(item, CallFeedback):
            call = self._calls.feedback(item.request_id, item.values, self._clock.now())
            if call is not None:
                self._tell_progress(call)
        elif isinstance(item, CallReplied):
            self._on_replied(item)
        else:
            self._on_replied(CallReplied(item.request_id, False, None, item.error, "disconnected"))

    def due(self) -> None:
        """The calls' deadline: cancel what ran too long, give up on what never answered, tell
        the progress held back."""
        now = self._clock.now()
        cancel, give_up = self._calls.overdue(now)
        for call in cancel:
            self._cancel(call, f"it took longer than {call.tool.rules.max_duration_s:g} s", now)
        for call in give_up:
            self._calls.finish(call.request_id)
            self._answer(call, self._calls.give_up(call))
        for call in self._calls.progress_due(now):
            self._tell_progress(call)

    def cancel_all(self, reason: str) -> None:
        """A stop: every action the robot runs for us is cancelled (services end by themselves)."""
        now = self._clock.now()
        for call in self._calls.active():
            if call.long_running:
                self._cancel(call, reason, now)

    def _send(self, request_id: str, send: Callable[[], Awaitable[None]]) -> None:
        async def attempt() -> None:
            try:
                await send()
            except ConnectionError as error:
                self._post(SendFailed(request_id, str(error) or "the bridge is not connected"))

        self._publish("robot tool", attempt)

    def _tell_progress(self, call: RobotCall) -> None:
        text = self._calls.take_progress(call, self._clock.now())
        session = self._session()
        if text and not call.orphaned and session is not None and session.serial == call.session:
            session.send(SendToolProgress(call.call_id, f"{call.tool.name} in progress: {text}"))
        self._publish_call(call.tool, call.request_id, call.arguments, "running", call, progress=text)

    def _on_replied(self, reply: CallReplied) -> None:
        call = self._calls.finish(reply.request_id)
        if call is None:
            self._calls.counters.stray_replies += 1
            return
        output = self._calls.result_of(call, reply.ok, reply.status, reply.values, reply.error, reply.code)
        self._answer(call, output)

    def _answer(self, call: RobotCall, output: str) -> None:
        result = json.loads(output)
        self._publish_call(
            call.tool, call.request_id, call.arguments, result["status"], call, error=result.get("error", "")
        )
        log.info("agent %s: %s (%s) ended: %s", self._agent_id, call.tool.name, call.request_id, output[:300])
        session = self._session()
        if call.orphaned or session is None or session.serial != call.session:
            # the call is gone with its session (or the provider withdrew it): a note instead
            self._tell_late(
                LATE_RESULT_NOTE.format(tool=call.tool.name, arguments=call.arguments[:200], result=output)
            )
            return
        self._deliver(call.call_id, output)

    def _cancel(self, call: RobotCall, reason: str, now: float) -> None:
        if not self._calls.mark_cancelled(call, reason, now):
            return
        log.info("agent %s: cancelling %s (%s): %s", self._agent_id, call.tool.name, call.request_id, reason)
        self._send(
            call.request_id, partial(self._port.cancel_action_goal, call.request_id, call.tool.ros_name)
        )

    def _publish_call(
        self,
        tool: RobotTool,
        request_id: str,
        arguments: str,
        state: str,
        call: RobotCall | None = None,
        progress: str = "",
        error: str = "",
    ) -> None:
        """A call's state on agent_metrics (started, progress, refused, ended)."""
        elapsed = 0.0 if call is None else round(self._clock.now() - call.started_at, 3)
        record = ToolCallMetrics(
            self._agent_id, request_id, tool.name, tool.kind, arguments[:200], state, progress, elapsed, error
        )
        self._publish("metrics", partial(self._port.publish_metrics, record))
