"""Gemini sessions with the agent as a process in a real ROS graph (issue 11): goAway answered by a
resumption with the newest handle and no utterance lost, and pause cycling that carries the
conversation into the reopened session. `byc agent --config agent_gemini.yaml` through the official
google-genai SDK against the Gemini Live emulator; helpers in agent_graph.py."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from agent_graph import (
    AgentGraph,
    GeminiEmulatorThread,
    corpus_utterance,
    gemini_emulator,
    gemini_graph,
    until,
)
from std_msgs.msg import Bool

from by_your_command.emulators.gemini_script import Say, Script, Turn
from by_your_command.emulators.gemini_wire import field_value

pytestmark = [pytest.mark.ros, pytest.mark.timeout(240)]

MS_PER_CHAR = 40
WAIT_S = 90.0


def records(graph: AgentGraph, kind: str) -> list[dict[str, Any]]:
    return [r for r in graph.probe.metric_records() if r["record"] == kind]


def resumed_with(api: GeminiEmulatorThread, connection: int) -> str | None:
    resumption = field_value(api.bodies("setup", connection)[0], "sessionResumption")
    return field_value(resumption, "handle") if resumption is not None else None


def carried(api: GeminiEmulatorThread, connection: int) -> list[tuple[str, str]]:
    """The conversation the emulator holds for a connection (a resumed one starts from its handle)."""
    return api._read(lambda: list(api.handle.sessions[connection].conversation.transcript))


def history_sent(api: GeminiEmulatorThread, connection: int) -> list[dict[str, Any]]:
    """clientContent without turnComplete: a fresh session seeded with the text history."""
    return [body for body in api.bodies("clientContent", connection) if not field_value(body, "turnComplete")]


def pcm16(samples: np.ndarray) -> bytes:
    return samples.astype("<i2").tobytes()


def test_go_away_resumes_with_the_newest_handle_and_the_utterance_around_it_is_answered(
    ros_namespace: str, tmp_path: Path
) -> None:
    # goAway after the second model turn, with half a second left: the user speaks right then.
    # The agent may answer it on the ending session, or lose that session under it and replay
    # the turn; either way it is answered once, and the next session resumes the conversation.
    script = Script(
        turns=(
            Turn(Say("First.")),
            Turn(Say("Second.")),
            Turn(Say("Third."), heard="turn left and look at the door"),
            Turn(Say("Fourth.")),
        ),
        ms_per_char=MS_PER_CHAR,
        go_away_after_turns=2,
        go_away_time_left_s=0.5,
    )
    answers = ["First.", "Second.", "Third.", "Fourth."]
    with (
        gemini_emulator(script) as api,
        gemini_graph(ros_namespace, tmp_path, [(api, "agent_gemini.yaml", {})]) as graph,
    ):
        probe, check = graph.probe, graph.check
        probe.type_text("one")
        until(lambda: probe.texts(probe.replies) == answers[:1], "the first reply", check, WAIT_S)
        probe.type_text("two")
        until(lambda: len(probe.replies) >= 2, "the second reply (then goAway)", check, WAIT_S)
        utterance = corpus_utterance(1)
        probe.activity.publish(Bool(data=True))
        probe.say(utterance)  # at once, in the goAway's last half second
        probe.activity.publish(Bool(data=False))
        until(lambda: len(probe.replies) >= 3, "the reply to the utterance around the goAway", check, WAIT_S)
        until(lambda: api.connections() == 2 or records(graph, "session"), "the ending session gone", check)
        probe.type_text("four")
        until(lambda: len(probe.replies) >= 4, "the reply on the resumed session", check, WAIT_S)
        turns = until(lambda: len(records(graph, "turn")) >= 4 and records(graph, "turn"), "turns", check)
        lines = graph.agents[0].stop()

        assert probe.texts(probe.replies) == answers
        assert [t["outcome"] for t in turns] == ["completed"] * 4
        assert api.connections() == 2
        # The new connection resumed (after the old socket was closed: the emulator refuses a
        # resume while the issuing connection is open) with the newest handle: the conversation
        # it continues holds every exchange once, none missing. No history was sent.
        assert resumed_with(api, 0) is None and resumed_with(api, 1)
        assert all(close.code != 1007 for close in api.closes()), api.closes()
        assert [text for role, text in carried(api, 1) if role == "model"] == answers
        assert history_sent(api, 1) == []
        # The utterance was answered once, from all of its audio, in one activity.
        ended = [c for c in (0, 1) if "activityEnd" in api.steps(c)]
        assert len(ended) == 1 and api.steps(ended[0]).count("activityEnd") == 1
        assert api.audio(ended[0]) == pcm16(utterance)
        assert any("goAway" in line for line in lines)


def test_pause_closes_the_session_and_speech_reopens_it_resuming_the_conversation(
    ros_namespace: str, tmp_path: Path
) -> None:
    script = Script(
        turns=(
            Turn(Say("I see a door."), heard="hello robot, what do you see?"),
            Turn(Say("It is red."), heard="turn left and look at the door"),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    with (
        gemini_emulator(script) as api,
        gemini_graph(
            ros_namespace, tmp_path, [(api, "agent_gemini.yaml", {"pause_timeout_s": 1.0})]
        ) as graph,
    ):
        probe, check = graph.probe, graph.check
        first, second = corpus_utterance(0), corpus_utterance(1)
        probe.say(first)
        until(lambda: probe.texts(probe.replies), "the first reply", check, WAIT_S)

        # The pause: nothing pending, nothing playing → the agent closes the paid session.
        closed = until(lambda: records(graph, "session"), "the session closed and billed", check, WAIT_S)[0]
        assert closed["close_reason"] == "pause of 1 s" and closed["turns"] == 1
        assert closed["billed_s"] > 0 and api.connections() == 1

        # The next speech reopens it; every chunk arrives while the new session connects.
        probe.activity.publish(Bool(data=True))
        probe.say(second)
        until(lambda: len(probe.replies) >= 2, "the reply in the reopened session", check, WAIT_S)
        graph.agents[0].stop()

        assert probe.texts(probe.replies) == ["I see a door.", "It is red."]
        assert api.connections() == 2
        # The conversation was carried: resumed with the first session's handle, nothing resent.
        assert resumed_with(api, 1) and history_sent(api, 1) == []
        assert carried(api, 1)[:2] == [("user", "hello robot, what do you see?"), ("model", "I see a door.")]
        assert all(close.code != 1007 for close in api.closes()), api.closes()
        # No audio lost to the reconnect: each session got its utterance whole.
        assert api.audio(0) == pcm16(first) and api.audio(1) == pcm16(second)
        assert api.steps(1)[:2] == ["setup", "activityStart"]
        assert api.audio_outside_activity_ms() == 0
