"""AgentReports on its own (agents/reports.py): the records a turn and a session leave on `metrics`,
from the state the runtime hands it. (Through the whole runtime: test_turns.py, test_sessions.py.)"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import pytest
from fake_port import FakePort

from by_your_command.agents.events import Usage
from by_your_command.agents.metrics import SessionMetrics, SessionOpenedMetrics, TurnMetrics
from by_your_command.agents.reply_audio import ReplyAudio
from by_your_command.agents.reports import AgentReports
from by_your_command.agents.turn import Turn

pytestmark = pytest.mark.unit


@dataclass
class FakeProvider:
    name: str = "fake"


@dataclass
class FakeSession:
    serial: int = 3
    provider: FakeProvider = field(default_factory=FakeProvider)
    opened_at: float | None = 10.0
    turns: int = 2
    usage: Usage = field(default_factory=lambda: Usage(input_text_tokens=7, output_text_tokens=5))


@dataclass
class Host:
    port: FakePort = field(default_factory=FakePort)
    t: float = 100.0
    conversation: str = "conv-1"
    sends: list[tuple[str, Callable[[], Awaitable[None]]]] = field(default_factory=list)

    def reports(self) -> AgentReports:
        return AgentReports(
            "agent",
            self.port,
            publish=lambda what, send: self.sends.append((what, send)),
            now=lambda: self.t,
            conversation_id=lambda: self.conversation,
        )

    def records(self) -> list[Any]:
        """What went on `metrics`, in order (the outbox's job in the runtime)."""
        sends, self.sends = self.sends, []
        assert {what for what, _ in sends} <= {"metrics"}
        asyncio.run(_in_order([send for _, send in sends]))
        return list(self.port.of("metrics"))


async def _in_order(sends: list[Callable[[], Awaitable[None]]]) -> None:
    for send in sends:
        await send()


def answered_turn(number: int = 4) -> Turn:
    turn = Turn(number, "voice", 98.0, 0)
    turn.ended_at = 99.0
    turn.first_audio_at = 99.25
    turn.usage = Usage(input_audio_tokens=30, output_audio_tokens=20)
    return turn


def reply_to(turn: int, published: bool = True) -> ReplyAudio:
    reply = ReplyAudio("r1", "i1", 24000, "agent-abc-3-1", 3, turn)
    reply.stream_started_at = 99.25 if published else None
    return reply


def test_a_turn_is_reported_with_its_latencies_from_the_end_of_the_users_speech() -> None:
    host = Host()
    turn = answered_turn()
    host.reports().turn(turn, "completed", "", 3, FakeSession(), reply_to(4))  # type: ignore[arg-type]
    assert host.records() == [
        TurnMetrics(
            "agent",
            "conv-1",
            3,
            4,
            "voice",
            "completed",
            250.0,
            1000.0,
            turn.usage,
            "fake",
            "",
            "agent-abc-3-1",
        )
    ]


def test_a_failed_turn_without_a_session_or_a_reply_of_its_own_says_why() -> None:
    host = Host()
    turn = Turn(5, "text", 99.5, 0)  # never ended: measured to now
    reports = host.reports()
    reports.turn(turn, "failed", "the provider session was lost", 3, None, reply_to(4))
    reports.turn(answered_turn(6), "completed", "", 3, None, reply_to(6, published=False))
    failed, unpublished = host.records()
    assert (failed.first_audio_ms, failed.reply_ms) == (None, 0.0)
    assert (failed.provider, failed.reason, failed.stream_id) == ("", "the provider session was lost", "")
    assert unpublished.stream_id == ""  # its audio never reached the player


def test_the_records_name_the_conversation_at_the_time() -> None:
    host = Host()
    reports = host.reports()
    reports.session_opened(FakeSession())  # type: ignore[arg-type]
    host.conversation = "conv-2"  # a reset
    reports.turn(answered_turn(), "completed", "", 3, None, None)
    opened, turn = host.records()
    assert opened == SessionOpenedMetrics("agent", "conv-1", 3, "fake")
    assert turn.conversation_id == "conv-2"


def test_a_closed_session_is_reported_with_what_the_vendor_bills() -> None:
    host = Host()
    session = FakeSession()
    host.reports().session_closed(session, "pause of 30 s", 12.34567)  # type: ignore[arg-type]
    assert host.records() == [
        SessionMetrics("agent", "conv-1", 3, 12.346, 2, "pause of 30 s", session.usage, "fake")
    ]


def test_a_session_that_never_opened_bills_nothing() -> None:
    host = Host()
    never = FakeSession(opened_at=None, turns=0, usage=Usage())
    host.reports().session_closed(never, "failed: refused", 4.0)  # type: ignore[arg-type]
    [record] = host.records()
    assert (record.billed_s, record.close_reason) == (0.0, "failed: refused")
