"""Agent metrics records → per-agent and per-provider summary, costs and diagnostics (pure)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from by_your_command.agents.events import Usage
from by_your_command.agents.metrics import SessionMetrics, SessionOpenedMetrics, TurnMetrics
from by_your_command.monitor.cost import Prices, estimate_cost
from by_your_command.monitor.records import BadRecord, SessionOpenRecord, Tokens, TurnRecord, parse_record
from by_your_command.monitor.summary import MAX_AGENTS, OK, WARN, AgentSummary, session_state

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
