"""The bridge's service calls and action goals on a real node: the call half of its RosGraph port.

Threads: every method here runs on the bridge's asyncio loop thread; rclpy answers (responses,
goal acceptance, feedback, results) arrive on the executor's thread, are converted to JSON there
(once) and posted back to the loop, which alone touches the bookkeeping and calls the core.
rclpy's ActionClient is not thread-safe (a goal answered before `send_goal_async` stored its
future is dropped as "unexpected"), so everything that touches an action client runs on the
executor thread (`executor.create_task`); once the executor has stopped (shutdown), directly.
Service clients lock internally: calls go out from the loop thread.
Waiting for a server polls the graph from the loop: it never blocks the executor or the loop.
Clients are made once per name and type: at startup for the allow-lists (`prepare`: discovery
is done before the first call), otherwise on first use; all are destroyed at shutdown.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from action_msgs.srv import CancelGoal
from rclpy.action import ActionClient
from rclpy.action.client import ClientGoalHandle
from rclpy.client import Client
from rclpy.node import Node
from rclpy.task import Future

from by_your_command.bridge.calls import (
    GOAL_ABORTED,
    GOAL_CANCELED,
    GOAL_SUCCEEDED,
    GOAL_UNKNOWN,
    ActionRule,
    CallOutcome,
    ServiceRule,
)
from by_your_command.bridge.core import PublishError
from by_your_command.ros.convert import ConversionError, Part, from_dict, interface_class, part_class, to_json

SERVER_POLL_S = 0.05  # how often a missing server is looked for in the graph
MIN_ACCEPT_WAIT_S = 1.0  # a server found at the deadline still gets this long to accept the goal


@dataclass(eq=False)
class _Call:
    name: str
    done: Callable[[CallOutcome], None]
    reported: bool = False
    waiter: asyncio.Task[None] | None = None
    timer: asyncio.TimerHandle | None = None


@dataclass(eq=False)
class _Goal:
    token: int
    name: str
    feedback: Callable[[str], None]
    done: Callable[[CallOutcome], None]
    cancel_wait_s: float  # after a cancel, how long to wait for the server's final result
    handle: ClientGoalHandle | None = None
    sent: bool = False
    cancel_requested: bool = False
    reported: bool = False
    waiter: asyncio.Task[None] | None = None
    timer: asyncio.TimerHandle | None = None
    # The latest feedback not yet handed to the loop (written by the executor thread): a flood of
    # feedback costs the loop one pending callback per goal, never a growing queue.
    lock: threading.Lock = field(default_factory=threading.Lock)
    latest: str | None = None


class RosCalls:
    def __init__(self, node: Node, loop: asyncio.AbstractEventLoop) -> None:
        self._node = node
        self._loop = loop
        self._services: dict[tuple[str, str], Client] = {}
        self._actions: dict[tuple[str, str], ActionClient] = {}
        self._calls: set[_Call] = set()
        self._goals: dict[int, _Goal] = {}
        self._direct = False  # the executor no longer spins: call rclpy from the loop thread
        self.feedback_coalesced = 0  # feedback replaced by newer feedback before the loop took it
        self.callback_errors = 0
        self.late_answers = 0  # goals answered after their client was told (timeout, cancel)

    # --- conversion (any thread) -----------------------------------------------------------------

    def convert_call(self, type_name: str, part: Part, args: dict[str, Any]) -> Any:
        try:
            return from_dict(part_class(type_name, part), args)
        except ConversionError as error:
            raise PublishError(str(error)) from None

    # --- services ----------------------------------------------------------------------------------

    def call_service(
        self,
        rule: ServiceRule,
        full_name: str,
        request: Any,
        timeout_s: float,
        done: Callable[[CallOutcome], None],
    ) -> None:
        call = _Call(full_name, done)
        self._calls.add(call)
        try:
            client = self._service_client(rule.type, full_name)
        except Exception as error:  # an uninstalled type the allow-list named: say so, keep serving
            self._finish_call(call, _internal(f"cannot create a client for {full_name}: {error}"))
            return
        call.waiter = self._loop.create_task(self._call(call, client, request, rule.timeout_s, timeout_s))

    async def _call(
        self, call: _Call, client: Client, request: Any, server_wait_s: float, timeout_s: float
    ) -> None:
        deadline = self._loop.time() + timeout_s
        wait_s = min(server_wait_s, timeout_s)
        if not await self._wait_ready(client.service_is_ready, wait_s, call):
            if not call.reported:
                error = f"service {call.name} is not available (waited {wait_s:g} s)"
                self._finish_call(call, CallOutcome(False, error=error, code="no_server"))
            return
        future = client.call_async(request)
        left = max(deadline - self._loop.time(), MIN_ACCEPT_WAIT_S)
        call.timer = self._loop.call_later(left, self._call_timed_out, call, client, future, timeout_s)
        future.add_done_callback(lambda answered: self._on_response(call, answered))

    def _on_response(self, call: _Call, future: Future) -> None:
        """Executor thread (or the loop's, if it answered at once): encode, hand to the loop."""
        if future.cancelled():
            return  # timed out: the client was told
        try:
            outcome = CallOutcome(True, to_json(future.result()))
        except Exception as error:  # noqa: BLE001 - reported to the client, never raised into rclpy
            outcome = _internal(f"service {call.name} answered with something unreadable: {error}")
        self._post(self._finish_call, call, outcome)

    def _call_timed_out(self, call: _Call, client: Client, future: Future, timeout_s: float) -> None:
        if call.reported:
            return
        client.remove_pending_request(future)
        future.cancel()
        self._finish_call(
            call,
            CallOutcome(
                False, error=f"service {call.name} did not answer within {timeout_s:g} s", code="timeout"
            ),
        )

    def _finish_call(self, call: _Call, outcome: CallOutcome) -> None:
        if call.reported:
            return
        call.reported = True
        if call.timer is not None:
            call.timer.cancel()
        self._calls.discard(call)
        call.done(outcome)

    def _service_client(self, type_name: str, full_name: str) -> Client:
        key = (full_name, type_name)
        client = self._services.get(key)
        if client is None:
            client = self._node.create_client(interface_class(type_name, "srv"), full_name)
            self._services[key] = client
        return client

    # --- actions -----------------------------------------------------------------------------------

    def send_goal(
        self,
        rule: ActionRule,
        full_name: str,
        goal: Any,
        token: int,
        feedback: Callable[[str], None],
        done: Callable[[CallOutcome], None],
    ) -> None:
        state = _Goal(token, full_name, feedback, done, rule.timeout_s)
        if token in self._goals:
            done(_internal(f"goal token {token} is already in use"))
            return
        self._goals[token] = state
        try:
            client = self._action_client(rule.type, full_name)
        except Exception as error:  # an uninstalled type the allow-list named
            self._finish_goal(state, _internal(f"cannot create a client for {full_name}: {error}"))
            return
        state.waiter = self._loop.create_task(self._send(state, client, goal, rule.timeout_s))

    async def _send(self, state: _Goal, client: ActionClient, goal: Any, timeout_s: float) -> None:
        deadline = self._loop.time() + timeout_s
        if not await self._wait_ready(client.server_is_ready, timeout_s, state):
            if not state.reported:
                self._finish_goal(
                    state,
                    CallOutcome(
                        False,
                        error=f"action {state.name} is not available (waited {timeout_s:g} s)",
                        code="no_server",
                        status=GOAL_ABORTED,
                    ),
                )
            return
        state.sent = True
        left = max(deadline - self._loop.time(), MIN_ACCEPT_WAIT_S)
        state.timer = self._loop.call_later(left, self._goal_not_accepted, state, timeout_s)
        self._on_ros(self._send_on_ros, state, client, goal)

    def _send_on_ros(self, state: _Goal, client: ActionClient, goal: Any) -> None:
        """Executor thread."""
        try:
            future = client.send_goal_async(goal, feedback_callback=lambda msg: self._on_feedback(state, msg))
            future.add_done_callback(lambda answered: self._on_goal_response(state, client, answered))
        except Exception as error:  # noqa: BLE001 - an exception here would stop the executor
            self._post(self._finish_goal, state, _internal(f"cannot send the goal to {state.name}: {error}"))

    def _on_goal_response(self, state: _Goal, client: ActionClient, future: Future) -> None:
        """Executor thread: accepted → ask for the result at once (nothing may be missed)."""
        try:
            handle = future.result()
            if handle is None or not handle.accepted:
                if handle is not None:
                    _forget_feedback_callback(client, handle)
                self._post(self._rejected, state)
                return
            handle.get_result_async().add_done_callback(lambda answered: self._on_result(state, answered))
            self._post(self._accepted, state, handle)
        except Exception as error:  # noqa: BLE001 - an exception here would stop the executor
            self.callback_errors += 1
            self._post(self._finish_goal, state, _internal(f"goal answer of {state.name} failed: {error}"))

    def _accepted(self, state: _Goal, handle: ClientGoalHandle) -> None:
        state.handle = handle
        if state.timer is not None:
            state.timer.cancel()
            state.timer = None
        if state.reported:  # accepted after the client was told it timed out: nobody waits for it
            self.late_answers += 1
            self._node.get_logger().warning(f"goal on {state.name} accepted too late: cancelling it")
            self._on_ros(self._cancel_on_ros, state, handle)
        elif state.cancel_requested:  # cancelled while the server decided
            self._send_cancel(state)

    def _rejected(self, state: _Goal) -> None:
        self._finish_goal(
            state, CallOutcome(False, error="goal rejected", code="rejected", status=GOAL_UNKNOWN)
        )

    def _on_feedback(self, state: _Goal, message: Any) -> None:
        """Executor thread: encode once; at most one hand-over per goal waits on the loop."""
        try:
            text = to_json(message.feedback)
        except Exception as error:  # noqa: BLE001 - never into rclpy
            self.callback_errors += 1
            self._node.get_logger().error(f"cannot convert feedback of {state.name}: {error}")
            return
        with state.lock:
            waiting = state.latest is not None
            state.latest = text
        if waiting:
            self.feedback_coalesced += 1
        else:
            self._post(self._flush_feedback, state)

    def _flush_feedback(self, state: _Goal) -> None:
        with state.lock:
            text, state.latest = state.latest, None
        if text is not None and not state.reported:
            state.feedback(text)

    def _on_result(self, state: _Goal, future: Future) -> None:
        """Executor thread."""
        try:
            response = future.result()
            outcome = _result_outcome(state.name, response.status, to_json(response.result))
        except Exception as error:  # noqa: BLE001 - reported to the client, never raised into rclpy
            outcome = _internal(f"result of {state.name} unreadable: {error}")
        self._post(self._finish_goal, state, outcome)

    def _goal_not_accepted(self, state: _Goal, timeout_s: float) -> None:
        if state.reported or state.handle is not None:
            return
        self._finish_goal(
            state,
            CallOutcome(
                False,
                error=f"action {state.name} did not accept the goal within {timeout_s:g} s",
                code="timeout",
                status=GOAL_ABORTED,
            ),
        )

    def cancel_goal(self, token: int) -> None:
        state = self._goals.get(token)
        if state is None or state.reported or state.cancel_requested:
            return
        state.cancel_requested = True
        if not state.sent:
            self._finish_goal(
                state,
                CallOutcome(
                    False, error="cancelled before the goal was sent", code="cancelled", status=GOAL_CANCELED
                ),
            )
        elif state.handle is not None:
            self._send_cancel(state)
        # else: sent, not yet answered: the cancel goes out at acceptance

    def _send_cancel(self, state: _Goal) -> None:
        assert state.handle is not None
        self._on_ros(self._cancel_on_ros, state, state.handle)
        # A server that never confirms (it died) must not leave the client waiting for ever.
        state.timer = self._loop.call_later(state.cancel_wait_s, self._cancel_unconfirmed, state)

    def _cancel_on_ros(self, state: _Goal, handle: ClientGoalHandle) -> None:
        """Executor thread (or the loop's once the executor stopped)."""
        try:
            handle.cancel_goal_async().add_done_callback(
                lambda answered: self._on_cancel_answer(state, answered)
            )
        except Exception as error:  # noqa: BLE001 - an exception here would stop the executor
            self.callback_errors += 1
            self._node.get_logger().error(f"cannot cancel the goal on {state.name}: {error!r}")

    def _on_cancel_answer(self, state: _Goal, future: Future) -> None:
        try:
            response = future.result()
            code = response.return_code if response is not None else -1
        except Exception:  # noqa: BLE001 - logged below as a failed cancel
            code = -1
        if code not in (CancelGoal.Response.ERROR_NONE, CancelGoal.Response.ERROR_GOAL_TERMINATED):
            self._node.get_logger().warning(f"{state.name} refused to cancel a goal (code {code})")

    def _cancel_unconfirmed(self, state: _Goal) -> None:
        if state.reported:
            return
        self._finish_goal(
            state,
            CallOutcome(
                False,
                error=f"no result from {state.name} within {state.cancel_wait_s:g} s of the cancel",
                code="timeout",
                status=GOAL_ABORTED,
            ),
        )

    def _finish_goal(self, state: _Goal, outcome: CallOutcome) -> None:
        if state.reported:
            return
        state.reported = True
        if state.timer is not None:
            state.timer.cancel()
            state.timer = None
        if self._goals.get(state.token) is state:
            del self._goals[state.token]
        state.done(outcome)

    def _action_client(self, type_name: str, full_name: str) -> ActionClient:
        key = (full_name, type_name)
        client = self._actions.get(key)
        if client is None:
            client = ActionClient(self._node, interface_class(type_name, "action"), full_name)
            self._actions[key] = client
        return client

    def prepare(self, services: list[tuple[str, str]], actions: list[tuple[str, str]]) -> None:
        """Create the clients of every allow-listed (type, full name) at startup: discovery then
        runs before the first call, which would otherwise spend its timeout finding the server.
        An interface that is not installed stops the start (ConversionError)."""
        for type_name, full_name in services:
            self._service_client(type_name, full_name)
        for type_name, full_name in actions:
            self._action_client(type_name, full_name)

    def servers(self) -> dict[str, int]:
        """1 if the service's / action's server is in the graph, else 0, by full name: 0 means a
        call would fail with no_server."""
        ready = {full: int(client.service_is_ready()) for (full, _), client in self._services.items()}
        ready.update({full: int(client.server_is_ready()) for (full, _), client in self._actions.items()})
        return ready

    @property
    def active_goals(self) -> int:
        return len(self._goals)

    # --- plumbing ----------------------------------------------------------------------------------

    async def _wait_ready(self, is_ready: Callable[[], bool], timeout_s: float, owner: _Call | _Goal) -> bool:
        """Poll the graph until the server is there; False on timeout or once the owner ended."""
        deadline = self._loop.time() + timeout_s
        while not owner.reported:
            if is_ready():
                return True
            left = deadline - self._loop.time()
            if left <= 0:
                return False
            await asyncio.sleep(min(SERVER_POLL_S, left))
        return False

    def _on_ros(self, function: Callable[..., None], *args: Any) -> None:
        executor = None if self._direct else self._node.executor
        if executor is None:
            function(*args)
        else:
            executor.create_task(function, *args)

    def _post(self, callback: Callable[..., None], *args: Any) -> None:
        try:
            self._loop.call_soon_threadsafe(callback, *args)
        except RuntimeError:
            pass  # the loop is closed: the node is shutting down

    def executor_stopped(self) -> None:
        """From here on rclpy is called from the loop thread (the executor no longer runs tasks)."""
        self._direct = True

    def destroy(self) -> None:
        """Loop thread, at shutdown: nothing more will be answered."""
        owners: list[_Call | _Goal] = [*self._calls, *self._goals.values()]
        for owner in owners:
            if owner.waiter is not None:
                owner.waiter.cancel()
            if owner.timer is not None:
                owner.timer.cancel()
        for client in self._services.values():
            self._node.destroy_client(client)
        for action_client in self._actions.values():
            action_client.destroy()
        self._services.clear()
        self._actions.clear()


def _forget_feedback_callback(client: ActionClient, handle: ClientGoalHandle) -> None:
    """rclpy drops a goal's feedback callback with its result; a rejected goal has none, and its
    callback (holding the client's session) would stay for ever."""
    callbacks = getattr(client, "_feedback_callbacks", None)
    if isinstance(callbacks, dict):
        callbacks.pop(bytes(handle.goal_id.uuid), None)


def _result_outcome(name: str, status: int, values_json: str) -> CallOutcome:
    if status == GOAL_SUCCEEDED:
        return CallOutcome(True, values_json, status=status)
    if status == GOAL_CANCELED:
        return CallOutcome(True, values_json, code="cancelled", status=status)
    if status == GOAL_ABORTED:
        return CallOutcome(True, values_json, status=status)
    return CallOutcome(
        False, error=f"action {name} ended with status {status}", code="internal_error", status=GOAL_ABORTED
    )


def _internal(text: str) -> CallOutcome:
    return CallOutcome(False, error=text, code="internal_error", status=GOAL_ABORTED)
