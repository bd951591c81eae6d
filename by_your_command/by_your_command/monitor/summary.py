"""Agent metrics summarised per agent and per provider: what the page, /diagnostics and the
`agent_summary` topic show (state, sessions, billed seconds, tokens, cost, latency, and the robot
tool calls running and just ended).

Fed with the raw `agent_metrics` texts in arrival order. Token totals come from closed sessions'
records (authoritative), plus the turns of a session still open; a session whose record never came
(the agent died, a message was lost) is folded in from its turns when the next session starts.
"""

from __future__ import annotations

import statistics
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from by_your_command.monitor.cost import Prices, estimate_cost
from by_your_command.monitor.records import (
    RUNNING,
    BadRecord,
    Record,
    SessionOpenRecord,
    SessionRecord,
    Tokens,
    ToolCallRecord,
    TurnRecord,
    parse_record,
)

MAX_AGENTS = 32  # records of further agent ids are counted, not kept: memory stays bounded
MAX_ACTIVE_CALLS = 32  # per agent (an agent has at most a few goals): the longest silent one goes first
RECENT_CALLS = 10  # ended calls kept per agent
OK, WARN = "ok", "warn"


def session_state(close_reason: str) -> str:
    """What a closed session means for the agent: idle (paused), cycled (rotated, reset or ended by
    the provider: the next turn opens a new one), failed, or stopped."""
    if close_reason.startswith("failed"):
        return "failed"
    if close_reason == "agent stopped":
        return "stopped"
    if close_reason.startswith("pause"):
        return "idle"
    return "cycled"


@dataclass(frozen=True)
class StatusReport:
    """One DiagnosticStatus, without ROS types: the node converts it."""

    level: str  # OK or WARN
    name: str  # appended to the node's name
    message: str
    values: dict[str, str]


@dataclass
class _Call:
    record: ToolCallRecord
    at: float  # when the record came (the summary's clock)

    def as_dict(self, now: float) -> dict[str, Any]:
        """The call as JSON-ready data; `age_s`: since its record came. A running call's
        `elapsed_s` is estimated for now, so a goal with no feedback still shows its time."""
        record, age = self.record, max(0.0, float(now - self.at))
        data: dict[str, Any] = {
            "request_id": record.request_id,
            "tool": record.tool,
            "kind": record.kind,
            "arguments": record.arguments,
            "state": record.state,
            "progress": record.progress,
            "elapsed_s": round(record.elapsed_s + (age if record.state == RUNNING else 0.0), 1),
            "age_s": round(age, 1),
        }
        if record.state != RUNNING:
            data["error"] = record.error
        return data


@dataclass
class _Agent:
    agent_id: str
    latency_turns: int
    provider: str = ""
    state: str = "unknown"  # nothing seen yet: "in session" once a session opened
    open_session: int | None = None
    open_tokens: Tokens = field(default_factory=Tokens)
    closed_tokens: Tokens = field(default_factory=Tokens)
    billed_s: float = 0.0  # our count: connect → close of each session
    provider_s: float = 0.0  # the provider's own count, from the sessions that report one
    priced_s: float = 0.0  # per session, the provider's count where it reports one, else ours
    sessions: int = 0
    sessions_unreported: int = 0  # a newer session began before this one's record arrived
    last_close_reason: str = ""
    turns: int = 0
    outcomes: Counter[str] = field(default_factory=Counter)
    last_outcome: str = ""
    last_first_audio_ms: float | None = None
    last_reply_ms: float | None = None
    first_audio: deque[float] = field(default_factory=deque)
    reply: deque[float] = field(default_factory=deque)
    active_calls: dict[str, _Call] = field(default_factory=dict)  # request_id → latest, oldest report first
    recent_calls: deque[_Call] = field(default_factory=lambda: deque(maxlen=RECENT_CALLS))  # newest last
    call_outcomes: Counter[str] = field(default_factory=Counter)  # ended calls per state (a fixed set)
    calls_evicted: int = 0  # running calls forgotten: more than MAX_ACTIVE_CALLS at once
    calls_unfinished: int = 0  # running when the agent stopped: no end record came
    calls_late: int = 0  # a running record for a call that had already ended

    @property
    def tokens(self) -> Tokens:
        return self.closed_tokens + self.open_tokens

    def opened(self, session: int) -> None:
        if self.open_session != session:
            if self.open_session is not None:  # its record never came: keep what its turns used
                self.closed_tokens = self.closed_tokens + self.open_tokens
                self.sessions += 1
                self.sessions_unreported += 1
            self.open_session, self.open_tokens = session, Tokens()
        self.state = "in session"

    def turn(self, record: TurnRecord) -> None:
        self.opened(record.session)  # also when the session_open record was lost
        self.open_tokens = self.open_tokens + record.tokens
        self.turns += 1
        self.outcomes[record.outcome] += 1
        self.last_outcome = record.outcome
        self.last_first_audio_ms, self.last_reply_ms = record.first_audio_ms, record.reply_ms
        if record.first_audio_ms is not None:
            _push(self.first_audio, record.first_audio_ms, self.latency_turns)
        _push(self.reply, record.reply_ms, self.latency_turns)

    def session(self, record: SessionRecord) -> None:
        if self.open_session == record.session:
            self.open_session, self.open_tokens = None, Tokens()  # the session's own total replaces them
        self.closed_tokens = self.closed_tokens + record.tokens
        self.billed_s += record.billed_s
        self.provider_s += record.tokens.session_s
        self.priced_s += record.tokens.session_s or record.billed_s  # what the vendor bills, when it says
        self.sessions += 1
        self.last_close_reason = record.close_reason
        if self.open_session is None:
            self.state = session_state(record.close_reason)
        if session_state(record.close_reason) == "stopped":
            # The bridge cancels a departed client's goals: nothing will report on these any more.
            self.calls_unfinished += len(self.active_calls)
            self.active_calls.clear()

    def tool_call(self, record: ToolCallRecord, now: float) -> None:
        call = _Call(record, now)
        if record.state != RUNNING:
            self.active_calls.pop(record.request_id, None)
            self.recent_calls.append(call)
            self.call_outcomes[record.state] += 1
            return
        if any(ended.record.request_id == record.request_id for ended in self.recent_calls):
            self.calls_late += 1  # out of order: its end is known, it is not running
            return
        self.active_calls.pop(record.request_id, None)  # re-inserted last: newest report last
        self.active_calls[record.request_id] = call
        while len(self.active_calls) > MAX_ACTIVE_CALLS:
            del self.active_calls[next(iter(self.active_calls))]
            self.calls_evicted += 1

    def calls(self, now: float) -> dict[str, Any]:
        active = sorted(self.active_calls.values(), key=lambda call: call.at - call.record.elapsed_s)
        return {
            "active_calls": [call.as_dict(now) for call in active],  # the earliest sent first
            "recent_calls": [call.as_dict(now) for call in reversed(self.recent_calls)],  # newest first
            "call_outcomes": dict(sorted(self.call_outcomes.items())),
            "calls_evicted": self.calls_evicted,
            "calls_unfinished": self.calls_unfinished,
            "calls_late": self.calls_late,
        }


def _push(window: deque[float], value: float, size: int) -> None:
    window.append(value)
    while len(window) > size:
        window.popleft()


def _median(window: deque[float]) -> float | None:
    return round(statistics.median(window), 1) if window else None


class AgentSummary:
    def __init__(
        self,
        prices: Mapping[str, Prices],
        currency: str = "USD",
        latency_turns: int = 50,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._prices = dict(prices)
        self._clock = clock
        self._currency = currency
        self._latency_turns = latency_turns
        self._agents: dict[str, _Agent] = {}
        self.invalid_records = 0
        self.last_invalid = ""  # why the last one was refused (diagnostics)
        self.ignored_records = 0  # from agents beyond MAX_AGENTS
        self.version = 0  # bumped on every change, so publishers can skip unchanged summaries

    def feed(self, text: str) -> Record | None:
        """Take one `agent_metrics` message; None (and counted) when it is not a valid record."""
        self.version += 1
        try:
            record = parse_record(text)
        except BadRecord as error:
            self.invalid_records += 1
            self.last_invalid = str(error)
            return None
        agent = self._agents.get(record.agent_id)
        if agent is None:
            if len(self._agents) >= MAX_AGENTS:
                self.ignored_records += 1
                return None
            agent = self._agents[record.agent_id] = _Agent(record.agent_id, self._latency_turns)
        if isinstance(record, ToolCallRecord):
            agent.tool_call(record, self._clock())
            return record
        if record.provider:
            agent.provider = record.provider
        if isinstance(record, TurnRecord):
            agent.turn(record)
        elif isinstance(record, SessionOpenRecord):
            agent.opened(record.session)
        else:
            agent.session(record)
        return record

    def _cost(self, provider: str, tokens: Tokens, billed_s: float) -> float | None:
        prices = self._prices.get(provider)
        return None if prices is None else round(estimate_cost(tokens, billed_s, prices), 6)

    def snapshot(self, agents_connected: int | None = None) -> dict[str, Any]:
        """The summary as JSON-ready data (the `agent_summary` topic and the page)."""
        agents = []
        now = self._clock()
        by_provider: dict[str, list[_Agent]] = {}
        for agent in sorted(self._agents.values(), key=lambda a: a.agent_id):
            by_provider.setdefault(agent.provider, []).append(agent)
            tokens = agent.tokens
            agents.append(
                {
                    "agent_id": agent.agent_id,
                    "provider": agent.provider,
                    "state": agent.state,
                    "open_session": agent.open_session,
                    "last_close_reason": agent.last_close_reason,
                    "sessions": agent.sessions,
                    "sessions_unreported": agent.sessions_unreported,
                    "billed_s": round(agent.billed_s, 3),
                    "provider_s": round(agent.provider_s, 3),
                    "turns": agent.turns,
                    "outcomes": dict(sorted(agent.outcomes.items())),
                    "input_tokens": tokens.input,
                    "output_tokens": tokens.output,
                    "cost": self._cost(agent.provider, tokens, agent.priced_s),
                    "last_first_audio_ms": agent.last_first_audio_ms,
                    "median_first_audio_ms": _median(agent.first_audio),
                    "last_reply_ms": agent.last_reply_ms,
                    "median_reply_ms": _median(agent.reply),
                    **agent.calls(now),
                }
            )
        providers: list[dict[str, Any]] = []
        costs: list[float] = []
        unpriced: list[str] = []
        for provider, members in sorted(by_provider.items()):
            tokens = sum((a.tokens for a in members), Tokens())
            billed = sum(a.billed_s for a in members)
            cost = self._cost(provider, tokens, sum(a.priced_s for a in members))
            if cost is None:
                unpriced.append(provider or "(unnamed)")
            else:
                costs.append(cost)
            providers.append(
                {
                    "provider": provider,
                    "sessions": sum(a.sessions for a in members),
                    "billed_s": round(billed, 3),
                    "provider_s": round(sum(a.provider_s for a in members), 3),
                    "input_tokens": tokens.input,
                    "output_tokens": tokens.output,
                    "cost": cost,
                }
            )
        return {
            "currency": self._currency,
            "agents_connected": agents_connected,
            "invalid_records": self.invalid_records,
            "ignored_records": self.ignored_records,
            "agents": agents,
            "providers": providers,
            "total_cost": round(sum(costs), 6),
            "unpriced_providers": unpriced,
        }

    def reports(self, agents_connected: int | None = None) -> list[StatusReport]:
        """/diagnostics: one status for the agents overall, one per agent (WARN after a failure)."""
        snapshot = self.snapshot(agents_connected)
        currency = snapshot["currency"]
        overall = {
            "agents_connected": str(agents_connected if agents_connected is not None else "unknown"),
            "agents_seen": str(len(snapshot["agents"])),
            "invalid_records": str(self.invalid_records),
            "ignored_records": str(self.ignored_records),
            f"total_cost_{currency}": f"{snapshot['total_cost']:.4f}",
        }
        if self.last_invalid:
            overall["last_invalid_record"] = self.last_invalid
        for provider in snapshot["providers"]:
            key = provider["provider"] or "unnamed"
            overall[f"{key}.billed_s"] = f"{provider['billed_s']:.1f}"
            overall[f"{key}.cost_{currency}"] = _money(provider["cost"])
        reports = [
            StatusReport(
                OK,
                "agents",
                f"{agents_connected if agents_connected is not None else '?'} agent(s) connected, "
                f"{len(snapshot['agents'])} seen; est. cost {snapshot['total_cost']:.4f} {currency}",
                overall,
            )
        ]
        for agent, data in zip(
            sorted(self._agents.values(), key=lambda a: a.agent_id), snapshot["agents"], strict=True
        ):
            failed = agent.last_outcome == "failed" or agent.state == "failed"
            values = {key: _value(value) for key, value in data.items() if key not in _LISTED}
            values.update({f"outcome.{name}": str(count) for name, count in data["outcomes"].items()})
            values.update(_call_values(data))
            message = (
                f"{agent.state}; {agent.turns} turn(s), {agent.sessions} session(s), "
                f"{agent.billed_s:.1f} s billed{_provider_count(agent.provider_s)}, "
                f"est. {_money(data['cost'])} {currency}"
            )
            if data["active_calls"]:
                message += f"; {len(data['active_calls'])} robot action(s) running"
            reports.append(StatusReport(WARN if failed else OK, f"agent {agent.agent_id}", message, values))
        return reports


def _provider_count(seconds: float) -> str:
    return f" (provider {seconds:.1f} s)" if seconds > 0 else ""


_LISTED = ("outcomes", "active_calls", "recent_calls", "call_outcomes")  # not one value each


def _call_values(data: dict[str, Any]) -> dict[str, str]:
    """Diagnostics of the robot tool calls: how many run, what each runs, how the last one ended."""
    values = {"calls_active": str(len(data["active_calls"]))}
    values.update({f"call_outcome.{name}": str(count) for name, count in data["call_outcomes"].items()})
    for call in data["active_calls"]:
        progress = f", {call['progress']}" if call["progress"] else ""
        values[f"call.{call['request_id']}"] = f"{call['tool']} running {call['elapsed_s']:.1f} s{progress}"
    if data["recent_calls"]:
        last = data["recent_calls"][0]
        error = f": {last['error']}" if last["error"] else ""
        values["last_call"] = f"{last['tool']} {last['state']} after {last['elapsed_s']:.1f} s{error}"
    return values


def _money(cost: float | None) -> str:
    return "no price" if cost is None else f"{cost:.4f}"


def _value(value: Any) -> str:
    return "" if value is None else str(value)
