"""The demo's pure parts: the plan (provider, key, sound source) and the narrator (lines, the end)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from by_your_command.bridge.client_messages import Lost, Received
from by_your_command.demo.plan import DemoSetupError, default_out_dir, make_plan
from by_your_command.demo.transcript import Narrator

pytestmark = pytest.mark.unit


def received(topic: str, msg: dict[str, object], at: float) -> Received:
    return Received(topic, "text", msg, at)


# -- plan ---------------------------------------------------------------------------------------


def test_offline_plays_the_bundled_file_into_a_wav_even_with_a_sound_card(tmp_path: Path) -> None:
    plan = make_plan("offline", None, tmp_path, {}, lambda: True)
    assert plan.provider.profile == "offline"
    assert plan.speech is not None and plan.speech.name == "demo_speech.wav"
    assert plan.reply_wav == tmp_path / "robot_said.wav" and plan.ends_by_itself


def test_a_cloud_demo_uses_mic_and_speaker_when_both_exist_else_the_file(tmp_path: Path) -> None:
    keys = {"OPENAI_API_KEY": "sk-test"}
    live = make_plan("openai", None, tmp_path, keys, lambda: True)
    assert (live.audio_source, live.audio_sink, live.ends_by_itself) == ("mic", "device", False)
    assert live.provider.profile == "oai_realtime"
    canned = make_plan("openai", None, tmp_path, keys, lambda: False)
    assert canned.speech is not None and canned.audio_sink.startswith("wav:")
    given = tmp_path / "mine.wav"
    given.write_bytes(b"")
    assert make_plan("gemini", given, tmp_path, {"GOOGLE_API_KEY": "k"}, lambda: True).speech == given


def test_missing_key_and_missing_file_are_setup_errors(tmp_path: Path) -> None:
    with pytest.raises(DemoSetupError, match="set GEMINI_API_KEY or GOOGLE_API_KEY"):
        make_plan("gemini", None, tmp_path, {"OPENAI_API_KEY": "sk"}, lambda: True)
    with pytest.raises(DemoSetupError, match="no such speech file"):
        make_plan("offline", tmp_path / "absent.wav", tmp_path, {}, lambda: False)


def test_results_default_to_the_state_directory_not_the_checkout() -> None:
    assert default_out_dir({"XDG_STATE_HOME": "/s"}) == Path("/s/by_your_command/demo")


# -- narrator -----------------------------------------------------------------------------------


def test_lines_say_what_was_heard_said_routed_refused_and_measured() -> None:
    narrator = Narrator("/robot1", started_at=100.0)
    lines = [
        *narrator.feed(received("prompt_transcript", {"data": "look up"}, 101.0)),
        *narrator.feed(
            received(
                "command_status",
                {"raw": "lookup", "command": "lookup", "accepted": True, "topic": "/robot1/arm_preset"},
                101.1,
            )
        ),
        *narrator.feed(
            received("command_status", {"raw": "fly", "accepted": False, "reason": "unknown command"}, 101.2)
        ),
        *narrator.feed(received("response_text", {"data": "Looking up."}, 101.3)),
        *narrator.feed(
            received(
                "agent_metrics",
                {
                    "data": json.dumps(
                        {"record": "turn", "first_audio_ms": 240.4, "reply_ms": 1310, "outcome": "completed"}
                    )
                },
                101.4,
            )  # fmt: skip
        ),
        *narrator.feed(
            received(
                "agent_metrics",
                {
                    "data": json.dumps(
                        {"record": "turn", "reply_ms": 900, "outcome": "failed", "reason": "lost"}
                    )
                },
                101.5,
            )
        ),
        *narrator.feed(received("attention_state", {"data": "asleep"}, 102.0)),
        *narrator.feed(received("attention_state", {"data": "asleep"}, 102.5)),  # no change: no line
        *narrator.feed(Lost("prompt_transcript", "text", 2, "the bridge dropped them", 103.0)),
        *narrator.feed(Lost("prompt_transcript", "text", None, "connection to the bridge lost", 104.0)),
        *narrator.feed(Lost("response_text", "text", None, "connection to the bridge lost", 104.0)),
    ]
    assert lines == [
        '[    1.0 s] heard      "look up"',
        "[    1.1 s] command    lookup -> arm_preset: accepted",
        '[    1.2 s] command    "fly" refused: unknown command',
        '[    1.3 s] robot      "Looking up."',
        "[    1.4 s] latency    first audio 240 ms, reply done 1310 ms (completed)",
        "[    1.5 s] latency    first audio -, reply done 900 ms (failed: lost)",
        "[    2.0 s] attention  asleep",
        "[    3.0 s] lost       2 prompt_transcript message(s): the bridge dropped them",
        "[    4.0 s] lost       messages in flight: connection to the bridge lost",
    ]
    tally = narrator.tally
    assert tally.routed == [("lookup", "arm_preset")] and tally.refused == [("fly", "unknown command")]
    assert (tally.heard, tally.replies, tally.turns, tally.lost) == (["look up"], ["Looking up."], 2, 2)


def test_the_demo_is_over_only_when_the_file_ended_and_the_last_reply_finished() -> None:
    narrator = Narrator(started_at=0.0)
    narrator.feed(received("playback_status", {"stream_id": "a-1-1", "speaking": True}, 10.0))
    narrator.feed(received("file_audio_done", {"data": True}, 11.0))
    assert not narrator.settled(30.0, grace_s=3.0)  # a reply is still playing
    narrator.feed(received("playback_status", {"stream_id": "a-1-1", "finished": True}, 12.0))
    assert not narrator.settled(14.0, grace_s=3.0)  # within the grace period
    narrator.feed(received("voice_activity", {"data": True}, 14.5))
    assert not narrator.settled(30.0, grace_s=3.0)  # someone is speaking
    narrator.feed(received("voice_activity", {"data": False}, 15.0))
    assert narrator.settled(18.0, grace_s=3.0)


def test_not_over_before_the_file_ended() -> None:
    narrator = Narrator(started_at=0.0)
    narrator.feed(received("file_audio_done", {"data": False}, 1.0))
    assert not narrator.settled(100.0, grace_s=1.0)
