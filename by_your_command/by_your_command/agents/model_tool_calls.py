"""The model's tool calls (docs/tools.md): each one decided (one of the robot's own tools,
`robot_command`, or a refusal), a command routed to the command processor once the provider events
queued behind its call are handled, its verdicts (or their deadline) answering it, a call the
provider cancelled withdrawn, and the results of one response sent together: to the turn they
answer, or as a turn of their own once that turn is over.

`tool_calls.py` decides and keeps; this acts on what it decides. The runtime owns it and calls it
from its one task (it starts no task and reads no clock of its own), so the state still changes only
there; what it needs of the runtime is handed in explicitly (no back-reference).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from functools import partial

from by_your_command.agents.config import AgentConfig, AgentRole
from by_your_command.agents.delegation import match_tool
from by_your_command.agents.events import ToolCall, ToolCallCancelled
from by_your_command.agents.inputs import CommandStatus, ToolCatalog
from by_your_command.agents.metrics import Counters
from by_your_command.agents.port import RobotPort
from by_your_command.agents.provider import ToolResult, ToolSpec
from by_your_command.agents.robot_calls import RobotCalls, is_stop_request
from by_your_command.agents.robot_runner import Publish
from by_your_command.agents.robot_tool import ROBOT_COMMAND_TOOL, result_json, verdicts_json
from by_your_command.agents.session import SendToolResults, Session
from by_your_command.agents.tool_calls import (
    PendingVerdicts,
    Refuse,
    ResponseResults,
    RunRobotTool,
    decide,
    robot_tool_spec,
)
from by_your_command.agents.turn import Turn
from by_your_command.tools.catalog import Catalog, CatalogError, RobotTool

log = logging.getLogger(__name__)

# A tool call's command is routed once the provider events queued behind it are handled (a
# cancellation may be among them), but never held behind more than this many.
MAX_ROUTE_DEFERRALS = 64


class ModelToolCalls:
    def __init__(
        self,
        config: AgentConfig,
        counters: Counters,
        verdicts: PendingVerdicts,
        robot_calls: RobotCalls,
        port: RobotPort,
        *,
        run: str,
        publish: Publish,
        now: Callable[[], float],
        turn: Callable[[], Turn | None],
        session: Callable[[], Session | None],
        start_robot: Callable[[int, RobotTool, ToolCall], None],
        stop_robot: Callable[[str], None],
        result_turn: Callable[[int, tuple[ToolResult, ...]], None],
        answered: Callable[[], None],
    ) -> None:
        """`verdicts` and `robot_calls` are shared with the robot's tool runner; `run` names this
        run in request ids. `turn()` is the committed turn being answered (None: none) and
        `session()` the provider session now. `start_robot(session serial, tool, call)` runs one of
        the robot's tools, `stop_robot(reason)` cancels its actions; `result_turn(session serial,
        results)` queues results whose turn is over as a turn of their own; `answered()`: a result
        is in, the reply deadline restarts."""
        self._config = config
        self._counters = counters
        self._verdicts = verdicts
        self._robot_calls = robot_calls
        self._port = port
        self._run = run
        self._publish = publish
        self._now = now
        self._turn = turn
        self._session = session
        self._start_robot = start_robot
        self._stop_robot = stop_robot
        self._result_turn = result_turn
        self._answered = answered
        self._results = ResponseResults()
        self._catalog = Catalog(())  # the robot's own tools, from `robot_tools` (docs/tools.md)
        self._requests = 0  # command requests sent: their ids name this run and this count
        self._route_deferrals = 0

    def new_request_id(self) -> str:
        """A command or robot tool request: its id names this agent, this run and this count."""
        self._requests += 1
        return f"{self._config.agent_id}-{self._run}-{self._requests}"

    def specs(self) -> tuple[ToolSpec, ...]:
        """The tools a new session offers the model (a tool-mode agent's only)."""
        if self._config.role is not AgentRole.TOOLS:
            return ()
        return (ROBOT_COMMAND_TOOL, *(robot_tool_spec(tool) for tool in self._catalog.tools))

    def take_catalog(self, item: ToolCatalog) -> bool:
        """The robot's tools; whether the tools offered to the model changed (a session is told
        its tools when it opens: the open one must be recycled)."""
        try:
            catalog = Catalog.from_json(item.text)
        except CatalogError as error:
            self._counters.inputs_invalid += 1
            log.warning("agent %s: the robot's tool list was refused: %s", self._config.agent_id, error)
            return False
        if catalog == self._catalog:
            return False
        self._catalog = catalog
        names = ", ".join(tool.name for tool in catalog.tools) or "none"
        log.info("agent %s: the robot's tools: %s", self._config.agent_id, names)
        return self._config.role is AgentRole.TOOLS

    def on_call(self, serial: int, turn: Turn | None, call: ToolCall, duplex: bool) -> None:
        """A tool call of session `serial`'s model, while `turn` is answered (None: none)."""
        self._counters.tool_calls += 1
        self._results.expect(serial, call.response_id, call.call_id, turn.number if turn else 0)
        if turn is not None:
            turn.tool_calls_open.add(call.call_id)
            turn.tool_responses.add(call.response_id)
        decision = decide(call, self._config.role is AgentRole.TOOLS, self._catalog)
        if isinstance(decision, RunRobotTool):
            self._start_robot(serial, decision.tool, call)
            return
        if isinstance(decision, Refuse):
            self.deliver(call.call_id, decision.output)
            return
        command = decision.command
        if is_stop_request(command):  # the model stops the robot: its actions too
            self._stop_robot(f"stopped ({command!r})")
        elif duplex and self._delegate_to_robot_tool(serial, call, command):
            return
        self._verdicts.add(
            call.call_id, self.new_request_id(), command, self._now() + self._config.tool_verdict_timeout_s
        )
        # routed by route(), after the provider events already queued behind this call

    def route(self, provider_backlog: int) -> None:
        """Publish the commands of tool calls once no provider event waits in the queue (the
        `provider_backlog` of them not handled yet): a cancellation that came with the call
        withdraws a command the robot never saw."""
        waiting = self._verdicts.unrouted()
        if not waiting:
            self._route_deferrals = 0
            return
        if provider_backlog > 0 and self._route_deferrals < MAX_ROUTE_DEFERRALS:
            self._route_deferrals += 1
            return
        self._route_deferrals = 0
        for call in waiting:
            self._verdicts.routed(call.request_id)
            self._publish(
                "command_request", partial(self._port.publish_command_request, call.request_id, call.command)
            )

    def on_cancelled(self, event: ToolCallCancelled) -> bool:
        """The provider withdrew calls; whether that cut the turn's last open ones (the provider cut
        its own turn when the user spoke: nothing more will answer it)."""
        turn = self._turn()
        had_open = turn is not None and bool(turn.tool_calls_open)
        for call_id in event.call_ids:
            robot_call = self._robot_calls.by_call_id(call_id)
            if robot_call is not None:  # the robot goes on (only a stop cancels); its end becomes a note
                robot_call.orphaned = True
                if turn is not None:
                    turn.tool_calls_open.discard(call_id)
                continue
            withdrawn = self._verdicts.cancel(call_id)
            if withdrawn is None:
                continue  # answered already (or never ours): nothing to withdraw
            call, routed = withdrawn
            self._counters.tool_calls_cancelled += 1
            if not routed:
                self._counters.commands_withheld += 1
            log.info(
                "agent %s: the provider cancelled tool call %s (%r): %s",
                self._config.agent_id,
                call_id,
                call.command,
                "the robot may already act on it" if routed else "never routed",
            )
            if turn is not None:
                turn.tool_calls_open.discard(call_id)
        for call_id in event.call_ids:
            self._results.withdraw(call_id)  # its result is never sent
        self._send_results()
        return turn is not None and had_open and not turn.tool_calls_open

    def on_verdict(self, verdict: CommandStatus) -> None:
        answered = self._verdicts.take(verdict)
        if answered is None:
            return  # one of several, or a verdict for what another agent (or a person) sent
        call, verdicts = answered
        self.deliver(call.call_id, verdicts_json(verdicts))

    def next_deadline(self) -> float | None:
        """When the first call waiting for its verdicts is answered without them."""
        return self._verdicts.next_deadline()

    def verdicts_late(self) -> None:
        for call in self._verdicts.expired(self._now()):
            self._counters.tool_timeouts += 1
            log.warning(
                "agent %s: no verdict for %r within %g s",
                self._config.agent_id,
                call.command,
                self._config.tool_verdict_timeout_s,
            )
            self.deliver(call.call_id, result_json(False, call.command, "no answer from the robot"))

    def waiting(self) -> int:
        """Calls waiting for their verdicts."""
        return len(self._verdicts)

    def drop_waiting(self) -> None:
        """The session is gone: its calls waiting for verdicts are dropped (none can be answered)."""
        for call in self._verdicts.expired(float("inf")):
            log.info("agent %s: tool call %s dropped with its session", self._config.agent_id, call.call_id)

    def forget_results(self) -> None:
        """The session closed: results only its own responses could take are dropped."""
        self._results.clear()

    def deliver(self, call_id: str, output: str) -> None:
        """A call's result (sent with the rest of its response's once all are in)."""
        self._results.answer(call_id, output)
        turn = self._turn()
        if turn is not None:
            turn.tool_calls_open.discard(call_id)
        self._answered()
        self._send_results()

    def response_done(self, response_id: str) -> None:
        """The response ended: no more calls come in it (its results may be complete now)."""
        self._results.response_done(response_id)
        self._send_results()

    def calls_of(self, response_id: str) -> list[str]:
        return self._results.calls_of(response_id)

    def _send_results(self) -> None:
        """Each response's results once it is done and all are in: one request for a reply. The
        results of a response whose turn is over (it started a robot action) make a turn of their
        own, after the reply in progress."""
        for serial, turn_number, results in self._results.take_ready():
            out = self._turn()
            if out is not None and out.number == turn_number:
                session = self._session()
                if session is not None and session.serial == serial:
                    session.send(SendToolResults(results))
            else:
                self._result_turn(serial, results)

    def _delegate_to_robot_tool(self, serial: int, call: ToolCall, said: str) -> bool:
        """A full-duplex delegation carries the user's words, not a tool: one of the robot's tools
        when they are its declared phrase (agents/delegation.py)."""
        specs = [robot_tool_spec(tool) for tool in self._catalog.tools]
        delegated = match_tool(said, specs)
        tool = self._catalog.get(delegated.tool) if delegated is not None else None
        if delegated is None or tool is None:
            return False
        log.info("agent %s: delegation %r → %s", self._config.agent_id, said[:80], tool.name)
        named = ToolCall(call.response_id, call.call_id, tool.name, delegated.arguments)
        self._start_robot(serial, tool, named)
        return True
