"""Calls of the robot's own tools (docs/tools.md): ROS actions, services and topics, run while the
conversation goes on. Pure bookkeeping, no I/O: the runtime sends what this decides.

A call is named twice: by the provider's call id (what its result answers) and by the bridge
request id (what the robot's replies echo). Replies are matched by request id only, never by tool
or text. An action's feedback reaches the model at most once per `feedback.every_s` (the latest
summary wins, the rest are counted); its result becomes the call's result, whenever it comes.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from by_your_command.tools.catalog import RobotTool

# Answered by the robot in this long after our own deadline, a reply is late (the bridge has its
# own timeouts; ours only catches a bridge that never answers).
REPLY_GRACE_S = 2.0
MAX_ACTIVE_CALLS = 16  # beyond this a call is refused: the robot cannot be doing more at once
MAX_RESULT_CHARS = 2000  # a result's values given to the model are cut to this (a map is not a reply)

_STOP_WORDS = {"stop", "halt", "freeze", "cancel", "abort"}
_FILLER_WORDS = {"it", "please", "now", "robot", "that", "everything", "all", "the", "right", "away", "oh"}


def is_stop_request(text: str) -> bool:
    """'stop', 'stop it', 'halt now please': a user asking the robot to stop everything (not
    'the bus stop' or 'don't stop'): a stop word and nothing but fillers."""
    words = re.findall(r"[a-z']+", text.lower())
    return (
        bool(words)
        and any(w in _STOP_WORDS for w in words)
        and all(w in _STOP_WORDS or w in _FILLER_WORDS for w in words)
    )


def call_result(tool: str, ok: bool, status: str, values: Any = None, error: str = "") -> str:
    """The result JSON every robot tool call answers with (docs/tools.md)."""
    out: dict[str, Any] = {"ok": ok, "tool": tool, "status": status}
    if ok and values is not None:
        text = json.dumps(values)
        out["result"] = values if len(text) <= MAX_RESULT_CHARS else {"truncated": text[:MAX_RESULT_CHARS]}
    if not ok:
        out["error"] = error
    return json.dumps(out)


# action_msgs/GoalStatus codes the bridge reports with a result
_GOAL_STATUS = {4: "succeeded", 5: "cancelled", 6: "failed"}


@dataclass
class RobotCall:
    call_id: str
    session: int  # the provider session that made it (only it can take the result as such)
    tool: RobotTool
    request_id: str
    arguments: str
    started_at: float
    deadline: float  # actions: cancelled at max_duration_s; services: no reply by then = timeout
    cancel_reason: str = ""  # why we cancelled it ("" = we did not)
    cancel_deadline: float | None = None  # cancelled, and the robot must confirm by then
    feedback_received: int = 0
    feedback_sent: int = 0
    progress: str = ""  # the latest feedback summary not yet given to the model
    progress_due: float = float("inf")
    last_progress_at: float = float("-inf")
    orphaned: bool = False  # the provider withdrew the call: its end is told as a note

    @property
    def long_running(self) -> bool:
        return self.tool.kind == "action"


@dataclass
class CallCounters:
    started: int = 0
    refused: int = 0  # rules or arguments: nothing sent to the robot
    succeeded: int = 0
    failed: int = 0
    cancelled: int = 0
    timeouts: int = 0
    feedback: int = 0
    feedback_sent: int = 0
    feedback_coalesced: int = 0  # summaries replaced by a newer one before they were sent
    stray_replies: int = 0  # replies naming no call of ours (late, or forged)


@dataclass
class RobotCalls:
    """The calls in flight, by request id."""

    calls: dict[str, RobotCall] = field(default_factory=dict)
    counters: CallCounters = field(default_factory=CallCounters)
    _last_started: dict[str, float] = field(default_factory=dict)  # per tool: its min_interval_s

    def __len__(self) -> int:
        return len(self.calls)

    def active(self) -> list[RobotCall]:
        return list(self.calls.values())

    def too_soon(self, tool: RobotTool, now: float) -> float:
        """Seconds still to wait before `tool` may run again (0: it may)."""
        last = self._last_started.get(tool.name)
        if last is None:
            return 0.0
        return max(0.0, last + tool.rules.min_interval_s - now)

    def start(self, call: RobotCall) -> None:
        self.calls[call.request_id] = call
        self._last_started[call.tool.name] = call.started_at
        self.counters.started += 1

    def finish(self, request_id: str) -> RobotCall | None:
        return self.calls.pop(request_id, None)

    def by_call_id(self, call_id: str) -> RobotCall | None:
        return next((c for c in self.calls.values() if c.call_id == call_id), None)

    def feedback(self, request_id: str, values: dict[str, Any], now: float) -> RobotCall | None:
        """Keep the newest summary; the call if its progress may be told now (else it waits)."""
        call = self.calls.get(request_id)
        if call is None:
            self.counters.stray_replies += 1
            return None
        call.feedback_received += 1
        self.counters.feedback += 1
        if call.progress:
            self.counters.feedback_coalesced += 1
        call.progress = call.tool.feedback_summary(values)
        every = call.tool.feedback.every_s if call.tool.feedback is not None else 0.0
        call.progress_due = max(now, call.last_progress_at + every)
        return call if call.progress_due <= now else None

    def take_progress(self, call: RobotCall, now: float) -> str:
        text, call.progress = call.progress, ""
        call.progress_due = float("inf")
        call.last_progress_at = now
        call.feedback_sent += 1
        self.counters.feedback_sent += 1
        return text

    def progress_due(self, now: float) -> list[RobotCall]:
        return [c for c in self.calls.values() if c.progress and c.progress_due <= now]

    def next_deadline(self) -> float | None:
        times = [
            c.cancel_deadline if c.cancel_deadline is not None else c.deadline for c in self.calls.values()
        ]
        times += [c.progress_due for c in self.calls.values() if c.progress]
        return min(times, default=None)

    def overdue(self, now: float) -> tuple[list[RobotCall], list[RobotCall]]:
        """(calls to cancel now: over their time; calls to give up on: no answer to a cancel or
        to a request within its time and the grace)."""
        cancel: list[RobotCall] = []
        give_up: list[RobotCall] = []
        for call in self.calls.values():
            if call.cancel_deadline is not None:
                if call.cancel_deadline <= now:
                    give_up.append(call)
            elif call.deadline <= now:
                (cancel if call.long_running else give_up).append(call)
        return cancel, give_up

    def mark_cancelled(self, call: RobotCall, reason: str, now: float) -> bool:
        """True if a cancel must be sent (the first reason wins)."""
        if call.cancel_deadline is not None:
            return False
        call.cancel_reason = reason
        call.cancel_deadline = now + call.tool.rules.timeout_s + REPLY_GRACE_S
        return True

    def result_of(self, call: RobotCall, ok: bool, status: int, values: Any, error: str, code: str) -> str:
        """The call's result JSON from the robot's answer, counted."""
        name = call.tool.name
        if call.tool.kind == "service":
            if ok:
                self.counters.succeeded += 1
                return call_result(name, True, "succeeded", values)
            self.counters.failed += 1
            return call_result(name, False, _failure_status(code), error=error or "the service failed")
        state = _GOAL_STATUS.get(status, "failed") if ok else _failure_status(code)
        if state == "succeeded":
            self.counters.succeeded += 1
            return call_result(name, True, state, values)
        if state == "cancelled":
            self.counters.cancelled += 1
            why = call.cancel_reason or "cancelled by the robot"
            return call_result(name, False, state, error=f"cancelled: {why}")
        self.counters.failed += 1
        detail = error or (json.dumps(values)[:300] if values else "")
        return call_result(
            name, False, state, error=f"the robot reported failure{': ' + detail if detail else ''}"
        )

    def give_up(self, call: RobotCall) -> str:
        self.counters.timeouts += 1
        if call.cancel_deadline is not None:
            what = f"cancelled ({call.cancel_reason}) but the robot did not confirm"
        else:
            what = f"no answer from the robot within {call.tool.rules.timeout_s:g} s"
        return call_result(call.tool.name, False, "timeout", error=what)

    def drop_all(self) -> Iterable[RobotCall]:
        calls = list(self.calls.values())
        self.calls.clear()
        return calls


def _failure_status(code: str) -> str:
    return {
        "rejected": "rejected",
        "cancelled": "cancelled",
        "timeout": "timeout",
        "no_server": "unavailable",
        "disconnected": "unavailable",
        "not_allowed": "refused",
        "wrong_type": "refused",
        "bad_args": "refused",
        "too_many": "refused",
    }.get(code, "failed")
