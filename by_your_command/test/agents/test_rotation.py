"""When the provider session closes (agents/rotation.py): after a pause, before its age limit (the
lower of ours and the provider's, less a margin), at once when asked at a boundary, with the first
reason given. (Through the runtime: test_sessions.py; the real graph: test_agent_sessions.py.)"""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from by_your_command.agents.rotation import ROTATION, SessionEnd

pytestmark = pytest.mark.unit


@dataclass
class Provider:
    max_session_s: float


@dataclass
class Session:
    opened_at: float | None
    provider: Provider

    def age(self, now: float) -> float:
        return 0.0 if self.opened_at is None else now - self.opened_at


def test_an_idle_session_closes_after_the_pause_or_before_the_lower_age_limit() -> None:
    end = SessionEnd(pause_timeout_s=10.0, max_session_s=600.0, rotation_margin_s=30.0)
    gemini = Session(opened_at=100.0, provider=Provider(max_session_s=60.0))
    assert end.rotation_age(gemini) == 30.0  # the provider's limit is lower: less the margin
    assert end.close_at(gemini, last_activity=110.0) == 120.0  # the pause first
    assert end.close_at(gemini, last_activity=125.0) == 130.0  # then the age limit
    assert not end.rotation_due(gemini, now=129.9)
    assert end.rotation_due(gemini, now=130.0)
    assert end.reason(gemini, now=130.0) == ROTATION
    assert end.reason(gemini, now=121.0) == "pause of 10 s"
    short = Session(opened_at=0.0, provider=Provider(max_session_s=20.0))
    assert end.rotation_age(short) == pytest.approx(18.0)  # a margin above the limit: 10 % of it
    long_lived = Session(opened_at=100.0, provider=Provider(max_session_s=3600.0))
    assert end.rotation_age(long_lived) == 570.0  # ours is lower
    connecting = Session(opened_at=None, provider=Provider(max_session_s=60.0))
    assert not end.rotation_due(connecting, now=1e6)
    assert end.close_at(connecting, last_activity=5.0) == 15.0
    assert not end.rotation_due(None, now=1e6)


def test_a_close_asked_for_is_due_from_when_it_was_first_asked_with_the_first_reason() -> None:
    end = SessionEnd(pause_timeout_s=10.0, max_session_s=600.0, rotation_margin_s=30.0)
    session = Session(opened_at=0.0, provider=Provider(max_session_s=3600.0))
    assert end.asked == ""
    end.recycle("the robot's tools changed", now=5.0)
    end.recycle("a stop's audio is in the provider's input", now=7.0)
    assert end.asked == "the robot's tools changed"
    assert end.close_at(session, last_activity=8.0) == 5.0  # a fixed time: it stays due
    end.recycle("new conversation (reset)", now=9.0, replace=True)
    end.provider_ends("the provider is ending the session (goAway)", now=9.5)
    assert end.asked == "the provider is ending the session (goAway)"  # the provider's end first
    assert end.recycling == "new conversation (reset)"
    assert end.close_at(session, last_activity=9.5) == 5.0
    end.closed()
    assert end.asked == "" and end.close_at(session, last_activity=9.5) == 19.5
