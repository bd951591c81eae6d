"""Agent metrics records → per-agent and per-provider summary, costs and diagnostics (pure)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from by_your_command.agents.events import Usage
from by_your_command.agents.metrics import SessionMetrics, SessionOpenedMetrics, ToolCallMetrics, TurnMetrics
from by_your_command.monitor.cost import Prices, estimate_cost
from by_your_command.monitor.records import (
    BadRecord,
    SessionOpenRecord,
    Tokens,
    ToolCallRecord,
    TurnRecord,
    parse_record,
)
from by_your_command.monitor.summary import (
    MAX_ACTIVE_CALLS,
    MAX_AGENTS,
    OK,
    RECENT_CALLS,
    WARN,
    AgentSummary,
    session_state,
)

pytestmark = pytest.mark.unit

OPENAI = Prices(
    input_text=4, input_audio=32, input_image=5, cached_input=0.4, output_text=16, output_audio=64
)


SESSION = (
    '{"record": "session", "agent_id": "a", "session": 1, "billed_s": BILLED, "turns": 1, "close_reason": ""}'
)


def turn(session: int, number: int, outcome: str = "completed", agent: str = "robot", **usage: int) -> str:
    record = TurnMetrics(
        agent,
        "c1",
        session,
        number,
        "voice",
        outcome,
        200.0 + number,
        900.0,
        Usage(**usage),
        "openai_realtime",
    )
    return json.dumps(record.as_dict())


def closed(session: int, billed_s: float, reason: str, agent: str = "robot", **usage: int) -> str:
    record = SessionMetrics(agent, "c1", session, billed_s, 2, reason, Usage(**usage), "openai_realtime")
    return json.dumps(record.as_dict())


def test_the_agents_own_records_are_read_back() -> None:
    record = parse_record(turn(3, 7, input_audio_tokens=10, cached_input_tokens=4, output_audio_tokens=20))
    assert record == TurnRecord(
        "robot",
        "openai_realtime",
        3,
        7,
        "completed",
        207.0,
        900.0,
        Tokens(input_audio=10, cached_input=4, output_audio=20),
    )


def opened(session: int, agent: str = "robot") -> str:
    return json.dumps(SessionOpenedMetrics(agent, "c1", session, "openai_realtime").as_dict())


def test_a_session_shows_as_soon_as_it_opens_before_any_turn() -> None:
    assert parse_record(opened(4)) == SessionOpenRecord("robot", "openai_realtime", 4)
    summary = AgentSummary({})
    summary.feed(opened(1))
    agent = summary.snapshot()["agents"][0]
    assert (agent["state"], agent["open_session"], agent["turns"], agent["sessions"]) == (
        "in session",
        1,
        0,
        0,
    )
    summary.feed(turn(1, 1, input_text_tokens=10))  # its turns count in the session it opened
    summary.feed(closed(1, 3.0, "pause of 2 s", input_text_tokens=10))
    summary.feed(opened(2))
    agent = summary.snapshot()["agents"][0]
    assert (agent["state"], agent["open_session"], agent["sessions"], agent["sessions_unreported"]) == (
        "in session",
        2,
        1,
        0,
    )


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("not json", "not JSON"),
        ("[1, 2]", "not a JSON object"),
        ('{"record": "turn"}', "agent_id"),
        ('{"record": "party", "agent_id": "a", "session": 1}', "record must be"),
        ('{"record": "session", "agent_id": "a", "session": -1}', "session"),
        ('{"record": "session", "agent_id": "a", "session": true}', "session"),
        ('{"record": "session_open", "agent_id": "a", "session": "1"}', "session"),
        (SESSION.replace("BILLED", "NaN"), "NaN"),
        (SESSION.replace("BILLED", "1e308"), "billed_s"),
        (
            '{"record": "turn", "agent_id": "a", "session": 1, "usage": {"output_audio_tokens": "many"}}',
            "usage.output_audio_tokens",
        ),
        (
            '{"record": "session", "agent_id": "a", "session": 1, "billed_s": 1, "turns": 1,'
            ' "close_reason": "", "usage": {"session_s": -2}}',
            "usage.session_s",
        ),
        ("[" * 60_000, "not JSON"),  # nesting deeper than the parser recurses
        ('{"x": "' + "y" * 70_000 + '"}', "characters"),
    ],
)
def test_anything_else_is_refused_with_a_reason(text: str, why: str) -> None:
    with pytest.raises(BadRecord, match=why):
        parse_record(text)


def test_tokens_are_counted_once_from_turns_then_from_the_session_record() -> None:
    summary = AgentSummary({"openai_realtime": OPENAI})
    summary.feed(turn(1, 1, input_audio_tokens=100, output_audio_tokens=200))
    summary.feed(turn(1, 2, input_audio_tokens=50, output_audio_tokens=100))
    agent = summary.snapshot(agents_connected=1)["agents"][0]
    assert (agent["state"], agent["open_session"], agent["turns"]) == ("in session", 1, 2)
    assert (agent["input_tokens"], agent["output_tokens"]) == (150, 300)
    # The session's own total (here a little more: its transcription) replaces the turns' sum.
    summary.feed(closed(1, 12.5, "pause of 2 s", input_audio_tokens=160, output_audio_tokens=300))
    snapshot = summary.snapshot(agents_connected=1)
    agent = snapshot["agents"][0]
    assert (agent["state"], agent["open_session"], agent["sessions"]) == ("idle", None, 1)
    assert (agent["input_tokens"], agent["output_tokens"], agent["billed_s"]) == (160, 300, 12.5)
    assert agent["cost"] == pytest.approx((160 * 32 + 300 * 64) / 1e6)
    assert snapshot["providers"] == [
        {
            "provider": "openai_realtime",
            "sessions": 1,
            "billed_s": 12.5,
            "provider_s": 0.0,
            "input_tokens": 160,
            "output_tokens": 300,
            "cost": agent["cost"],
        }
    ]
    assert snapshot["total_cost"] == pytest.approx(agent["cost"])


def test_a_session_whose_record_never_came_is_kept_from_its_turns() -> None:
    summary = AgentSummary({})
    summary.feed(turn(1, 1, input_text_tokens=10))
    summary.feed(turn(2, 2, input_text_tokens=5))  # session 1's record was lost
    agent = summary.snapshot()["agents"][0]
    assert (
        agent["input_tokens"],
        agent["sessions"],
        agent["sessions_unreported"],
        agent["open_session"],
    ) == (15, 1, 1, 2)
    assert agent["cost"] is None  # no price for this provider: said, not guessed
    assert summary.snapshot()["unpriced_providers"] == ["openai_realtime"]


@pytest.mark.parametrize(
    ("reason", "state"),
    [
        ("pause of 2 s", "idle"),
        ("rotation before the limit", "cycled"),
        ("new conversation (reset)", "cycled"),
        ("the provider is ending the session (go away)", "cycled"),
        ("failed: connection lost", "failed"),
        ("agent stopped", "stopped"),
    ],
)
def test_a_closed_session_says_why(reason: str, state: str) -> None:
    assert session_state(reason) == state


def test_latency_medians_over_the_last_turns() -> None:
    summary = AgentSummary({}, latency_turns=3)
    for number in range(1, 6):  # first audio 201..205 ms
        summary.feed(turn(1, number))
    agent = summary.snapshot()["agents"][0]
    assert (agent["last_first_audio_ms"], agent["median_first_audio_ms"]) == (205.0, 204.0)


def test_bad_records_and_agents_beyond_the_bound_are_counted_not_kept() -> None:
    summary = AgentSummary({})
    assert summary.feed("{oops") is None
    for index in range(MAX_AGENTS + 3):
        summary.feed(turn(1, 1, agent=f"agent{index}"))
    snapshot = summary.snapshot()
    assert (len(snapshot["agents"]), snapshot["ignored_records"], snapshot["invalid_records"]) == (
        MAX_AGENTS,
        3,
        1,
    )
    overall = summary.reports()[0]
    assert overall.values["invalid_records"] == "1" and "not JSON" in overall.values["last_invalid_record"]


def test_diagnostics_per_agent_warn_after_a_failure() -> None:
    summary = AgentSummary({"openai_realtime": OPENAI})
    summary.feed(turn(1, 1, agent="conversation", output_audio_tokens=1000))
    summary.feed(turn(1, 1, "failed", agent="command"))
    reports = {report.name: report for report in summary.reports(agents_connected=2)}
    assert set(reports) == {"agents", "agent command", "agent conversation"}
    assert reports["agents"].values["agents_connected"] == "2"
    assert (reports["agent command"].level, reports["agent conversation"].level) == (WARN, OK)
    values: dict[str, Any] = reports["agent conversation"].values
    assert values["provider"] == "openai_realtime" and values["output_tokens"] == "1000"
    assert values["cost"] == "0.064" and values["outcome.completed"] == "1"
    assert reports["agents"].values["openai_realtime.cost_USD"] == "0.0640"


def test_cost_prices_tokens_per_kind_cached_input_and_session_minutes() -> None:
    tokens = Tokens(
        input_text=1000,
        input_audio=2000,
        input_image=100,
        cached_input=500,
        output_text=300,
        output_audio=400,
    )
    prices = Prices(1.0, 10.0, 5.0, 0.5, 2.0, 20.0, session_minute=0.6)
    # 500 cached tokens taken off the dearest input kind (audio) and priced at the cached price.
    expected = (
        1000 * 1.0 + 1500 * 10.0 + 100 * 5.0 + 500 * 0.5 + 300 * 2.0 + 400 * 20.0
    ) / 1e6 + 0.6 * 90 / 60
    assert estimate_cost(tokens, 90.0, prices) == pytest.approx(expected)
    assert estimate_cost(tokens, 90.0, Prices()) == 0.0
    with pytest.raises(ValueError, match="input_audio"):
        Prices(input_audio=-1.0)


def test_a_per_second_provider_is_priced_by_its_own_count_when_it_reports_one() -> None:
    """GPT-Live bills open session time and says how much (usage.session_s): that count is priced;
    a session that reports none is priced by our connect → close seconds."""
    summary = AgentSummary({"gpt_live": Prices(session_minute=0.06)})

    def session(number: int, billed_s: float, server_s: float) -> str:
        usage = Usage(session_s=server_s)
        return json.dumps(
            SessionMetrics("robot", "c1", number, billed_s, 1, "pause", usage, "gpt_live").as_dict()
        )

    summary.feed(session(1, billed_s=61.0, server_s=60.0))
    summary.feed(session(2, billed_s=30.0, server_s=0.0))  # reported none
    [agent] = summary.snapshot()["agents"]
    assert (agent["billed_s"], agent["provider_s"]) == (91.0, 60.0)
    assert agent["cost"] == pytest.approx(0.06 * (60.0 + 30.0) / 60)
    [provider] = summary.snapshot()["providers"]
    assert provider["provider_s"] == 60.0 and provider["cost"] == pytest.approx(agent["cost"])
    [_, report] = summary.reports()
    assert "91.0 s billed (provider 60.0 s)" in report.message
    assert report.values["provider_s"] == "60.0"


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def call(
    request_id: str,
    state: str = "running",
    progress: str = "",
    elapsed_s: float = 0.0,
    error: str = "",
    tool: str = "go_to",
    agent: str = "robot",
) -> str:
    record = ToolCallMetrics(
        agent, request_id, tool, "action", '{"place": "kitchen"}', state, progress, elapsed_s, error
    )
    return json.dumps(record.as_dict())


def test_a_tool_call_record_is_read_back() -> None:
    assert parse_record(call("robot-1-3", "failed", "1.5 m left", 4.25, "goal aborted")) == ToolCallRecord(
        "robot",
        "robot-1-3",
        "go_to",
        "action",
        '{"place": "kitchen"}',
        "failed",
        "1.5 m left",
        4.25,
        "goal aborted",
    )


@pytest.mark.parametrize(
    ("change", "why"),
    [
        ({"state": "exploded"}, "state: expected one of running"),
        ({"kind": "rocket"}, "kind: expected one of action"),
        ({"request_id": ""}, "request_id"),
        ({"request_id": "r" * 201}, "request_id"),
        ({"elapsed_s": -1}, "elapsed_s"),
        ({"arguments": {"place": "kitchen"}}, "arguments"),
        ({"tool": None}, "tool"),
    ],
)
def test_a_bad_tool_call_record_is_refused_with_a_reason(change: dict[str, Any], why: str) -> None:
    with pytest.raises(BadRecord, match=why):
        parse_record(json.dumps({**json.loads(call("r1")), **change}))


def test_active_calls_show_their_latest_progress_and_leave_when_they_end() -> None:
    clock = Clock()
    summary = AgentSummary({}, clock=clock)
    summary.feed(call("r1"))
    clock.now += 1.0
    summary.feed(call("r2", tool="dock"))
    clock.now += 4.0
    summary.feed(call("r1", progress="distance_remaining 2.4", elapsed_s=5.0))
    clock.now += 2.5  # no record since: the running call's time still goes on
    agent = summary.snapshot()["agents"][0]
    assert agent["active_calls"] == [
        {
            "request_id": "r1",
            "tool": "go_to",
            "kind": "action",
            "arguments": '{"place": "kitchen"}',
            "state": "running",
            "progress": "distance_remaining 2.4",
            "elapsed_s": 7.5,
            "age_s": 2.5,
        },
        {
            "request_id": "r2",
            "tool": "dock",
            "kind": "action",
            "arguments": '{"place": "kitchen"}',
            "state": "running",
            "progress": "",
            "elapsed_s": 6.5,
            "age_s": 6.5,
        },
    ]
    assert (agent["recent_calls"], agent["call_outcomes"]) == ([], {})

    summary.feed(call("r1", "succeeded", elapsed_s=8.0))
    clock.now += 1.0
    summary.feed(call("r2", "failed", elapsed_s=8.6, error="goal aborted", tool="dock"))
    summary.feed(call("r1", progress="late feedback", elapsed_s=7.9))  # after its end: not running again
    agent = summary.snapshot()["agents"][0]
    assert agent["active_calls"] == []
    assert [
        (c["request_id"], c["state"], c["elapsed_s"], c["error"], c["age_s"]) for c in agent["recent_calls"]
    ] == [
        ("r2", "failed", 8.6, "goal aborted", 0.0),  # newest first
        ("r1", "succeeded", 8.0, "", 1.0),
    ]
    assert agent["call_outcomes"] == {"failed": 1, "succeeded": 1}
    assert agent["calls_late"] == 1
    # A call refused before it ran ends without ever running.
    summary.feed(call("r3", "refused", error="the robot is asleep"))
    assert summary.snapshot()["agents"][0]["recent_calls"][0]["state"] == "refused"


def test_calls_are_bounded_however_many_request_ids_come() -> None:
    clock = Clock()
    summary = AgentSummary({}, clock=clock)
    for index in range(MAX_ACTIVE_CALLS):
        summary.feed(call(f"flood-{index}"))
    summary.feed(call("flood-0", progress="still here"))  # a fresh report: no longer the most silent
    for index in range(MAX_ACTIVE_CALLS, MAX_ACTIVE_CALLS + 10):
        summary.feed(call(f"flood-{index}"))
    active = {c["request_id"] for c in summary.snapshot()["agents"][0]["active_calls"]}
    assert len(active) == MAX_ACTIVE_CALLS and "flood-1" not in active  # the longest silent went first
    assert "flood-0" in active and f"flood-{MAX_ACTIVE_CALLS + 9}" in active
    for index in range(1000):
        summary.feed(call(f"more-{index}"))
    for index in range(RECENT_CALLS + 5):
        summary.feed(call(f"done-{index}", "succeeded"))
    agent = summary.snapshot()["agents"][0]
    assert len(agent["active_calls"]) == MAX_ACTIVE_CALLS
    assert agent["calls_evicted"] == 1010
    assert len(agent["recent_calls"]) == RECENT_CALLS
    assert agent["recent_calls"][0]["request_id"] == f"done-{RECENT_CALLS + 4}"
    assert agent["call_outcomes"] == {"succeeded": RECENT_CALLS + 5}  # counted, though not all kept


def test_an_agent_that_stops_leaves_no_call_running() -> None:
    summary = AgentSummary({}, clock=Clock())
    summary.feed(call("r1"))
    summary.feed(closed(1, 3.0, "pause of 2 s"))  # a session closes: the goal runs on
    assert len(summary.snapshot()["agents"][0]["active_calls"]) == 1
    summary.feed(closed(2, 3.0, "agent stopped"))
    agent = summary.snapshot()["agents"][0]
    assert (agent["active_calls"], agent["calls_unfinished"]) == ([], 1)


def test_diagnostics_say_what_runs_and_how_the_last_call_ended() -> None:
    clock = Clock()
    summary = AgentSummary({}, clock=clock)
    summary.feed(turn(1, 1))
    summary.feed(call("r1", progress="distance_remaining 2.4", elapsed_s=3.0))
    summary.feed(call("r0", "timeout", elapsed_s=10.0, error="no answer from /dock", tool="dock"))
    report = {report.name: report for report in summary.reports()}["agent robot"]
    assert report.level == OK  # a robot action that failed is the robot's news, not the agent's fault
    assert "1 robot action(s) running" in report.message
    assert report.values["calls_active"] == "1"
    assert report.values["call.r1"] == "go_to running 3.0 s, distance_remaining 2.4"
    assert report.values["last_call"] == "dock timeout after 10.0 s: no answer from /dock"
    assert report.values["call_outcome.timeout"] == "1"
    assert not any(key in report.values for key in ("active_calls", "recent_calls", "call_outcomes"))
    # The summary topic carries them as JSON.
    assert json.loads(json.dumps(summary.snapshot()))["agents"][0]["active_calls"][0]["request_id"] == "r1"
