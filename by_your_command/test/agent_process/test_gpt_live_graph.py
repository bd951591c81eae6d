"""The GPT-Live agent as a process in a real ROS graph (issue 36): ros_ai_bridge, simple_audio_player
(WAV sink) and command_processor as processes, `byc agent --config agent_gpt_live.yaml` (echo_mode
aec, as the gpt_live profile runs it) talking through the official SDK to the GPT-Live emulator
(`byc emulate gpt-live`'s server), and a probe node standing in for the VAD. The emulator takes its
turn when it hears the user stop (energy), as the real model does; helpers in gpt_live_graph.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from agent_graph import CONFIG_DIR, FAKE_KEY, corpus_utterance, until
from by_your_command_msgs.msg import Interruption
from gpt_live_graph import at_24k, live_graph, say_live
from std_msgs.msg import Bool

from by_your_command.audio.pcm import read_wav
from by_your_command.emulators.gpt_live_script import Delegate, Say, Script, Turn
from by_your_command.emulators.synthetic_speech import speech_pcm

pytestmark = [pytest.mark.ros, pytest.mark.timeout(180)]

MS_PER_CHAR = 40  # reply audio per character (emulator): short replies, quick tests
PACE = 0.5  # reply audio streamed at twice real time
WAIT_S = 60.0  # condition waits: generous, the machine is shared and has 2 cores


def script(*turns: Turn, **knobs: object) -> Script:
    return Script(turns=turns, ms_per_char=MS_PER_CHAR, pace=PACE, **knobs)  # type: ignore[arg-type]


def test_a_spoken_question_gets_a_spoken_reply_played_by_the_player(
    ros_namespace: str, tmp_path: Path
) -> None:
    wav = tmp_path / "played.wav"
    with live_graph(
        ros_namespace, tmp_path, script(Turn(Say("I see a door."), heard="what do you see")), wav=wav
    ) as graph:
        probe, check = graph.probe, graph.check
        utterance = corpus_utterance(0)
        probe.say(utterance)
        until(lambda: probe.texts(probe.replies) == ["I see a door."], "the spoken reply", check, WAIT_S)
        until(graph.finished_streams, "the reply played to its end", check, WAIT_S)
        assert probe.texts(probe.transcripts) == ["what do you see"]  # the model's input transcript
        lines = graph.stop_agent()
        graph.stop_player()

        start = graph.api.session_start(0)
        assert start["model"] == "gpt-live-1" and start["audio"]["format"] == {
            "type": "audio/pcm",
            "rate": 24000,
        }
        assert start["delegation"]["type"] == "client"  # the robot's tools run here
        # The utterance reached the model whole, resampled to the session's rate, in one piece.
        assert at_24k(utterance) in graph.api.appended(0)
        assert graph.api.connections() == 1
        assert any("session 1 closed (agent stopped)" in line for line in lines), "\n".join(lines)

    heard, rate, _ = read_wav(wav)
    assert rate == 24000
    assert heard.tobytes() == speech_pcm("I see a door.", MS_PER_CHAR), "heard whole, nothing else"


def test_a_refused_api_key_is_one_fatal_config_error_without_retries(
    ros_namespace: str, tmp_path: Path
) -> None:
    with live_graph(
        ros_namespace, tmp_path, script(rejected_api_keys=(FAKE_KEY,)), options=("--verbose",)
    ) as graph:
        graph.probe.say(corpus_utterance(0))  # the session opens on speech: the handshake is refused
        assert graph.agent.wait(timeout=WAIT_S) == 1  # a config error: the agent stops, no retry
        lines = graph.agent_out.finish()
        # One attempt, refused at the handshake: no retry, let alone a storm of them.
        assert (graph.api.refused_handshakes(), graph.api.connections()) == (1, 0)
    text = "\n".join(lines)
    errors = [line for line in lines if " ERROR " in line or "Traceback" in line]
    assert len(errors) == 1, text
    assert "OpenAI refused the API key" in errors[0] and "OPENAI_API_KEY" in errors[0], text
    assert FAKE_KEY not in text and FAKE_KEY[-6:] not in text  # not even the emulator's masked echo


def test_a_dropped_connection_is_recovered_by_a_new_session_on_the_next_speech(
    ros_namespace: str, tmp_path: Path
) -> None:
    story = "Once upon a time there was a robot who loved to talk."
    turns = (
        Turn(Say(story), heard="tell me a story", drop_after_ms=300),
        Turn(Say("Second."), heard="are you there"),
    )
    with live_graph(ros_namespace, tmp_path, script(*turns), wav=tmp_path / "played.wav") as graph:
        probe, check, api = graph.probe, graph.check, graph.api
        probe.say(corpus_utterance(0))
        closed = until(lambda: graph.records("session"), "the lost session reported", check, WAIT_S)[0]
        assert closed["close_reason"].startswith("failed: "), closed
        until(lambda: api.open_connections() == 0, "the dropped connection gone", check, WAIT_S)
        assert graph.agent.poll() is None  # a lost connection is not fatal

        probe.activity.publish(Bool(data=True))
        probe.say(corpus_utterance(1))
        until(lambda: "Second." in probe.texts(probe.replies), "the reply on a new session", check, WAIT_S)
        until(lambda: any(s.finished for s in list(probe.playback)), "the second reply played", check, WAIT_S)
        assert api.connections() == 2
        lines = graph.stop_agent()
        # The new session started with what was said before the drop.
        history = [item["content"][0]["text"] for item in api.session_start(1).get("input", [])]
        assert "tell me a story" in history, history
        assert any("session 2 closed (agent stopped)" in line for line in lines), "\n".join(lines)


def test_a_pause_closes_the_session_and_the_next_speech_opens_one_with_the_conversation(
    ros_namespace: str, tmp_path: Path
) -> None:
    turns = (
        Turn(Say("I see a door."), heard="what do you see"),
        Turn(Say("It is red."), heard="what colour"),
    )
    wav = tmp_path / "played.wav"
    with live_graph(ros_namespace, tmp_path, script(*turns), wav=wav, pause_timeout_s=1.0) as graph:
        probe, check, api = graph.probe, graph.check, graph.api
        first, second = corpus_utterance(0), corpus_utterance(1)
        probe.say(first)
        until(graph.finished_streams, "the first reply played", check, WAIT_S)

        # The pause: nothing pending, nothing playing → the agent closes the session billed by the second.
        closed = until(lambda: graph.records("session"), "the session closed after the pause", check, WAIT_S)[
            0
        ]
        assert closed["close_reason"] == "pause of 1 s", closed
        until(lambda: api.open_connections() == 0, "the emulator saw the session close", check, WAIT_S)
        assert "session.close" in api.types(0)  # closed in order, so billing stops at once
        assert api.connections() == 1

        # The next speech opens a new session, started with the earlier conversation as items.
        probe.activity.publish(Bool(data=True))
        probe.say(second)
        until(
            lambda: len(graph.finished_streams()) >= 2, "the reply in the new session played", check, WAIT_S
        )
        assert api.connections() == 2
        assert probe.texts(probe.replies) == ["I see a door.", "It is red."]
        graph.stop_agent()
        graph.stop_player()

        history = [(item["role"], item["content"][0]["text"]) for item in api.session_start(1)["input"]]
        assert history == [("user", "what do you see"), ("assistant", "I see a door.")]
        assert api.session_start(1)["instructions"] == api.session_start(0)["instructions"]
        # No audio lost to the reconnect: the second utterance reached the new session whole.
        assert at_24k(first) in api.appended(0) and at_24k(second) in api.appended(1)

    heard, _, _ = read_wav(wav)
    assert heard.tobytes() == speech_pcm("I see a door.", MS_PER_CHAR) + speech_pcm("It is red.", MS_PER_CHAR)


def test_speech_over_a_reply_makes_the_model_yield_and_the_player_cuts_it(
    ros_namespace: str, tmp_path: Path
) -> None:
    story = "Once upon a time there was a robot who loved to talk about everything it saw. " * 4
    turns = (
        Turn(Say(story), heard="tell me a story"),
        Turn(Say("It is red."), heard="what colour"),
    )
    # At real time, as the model speaks: the user talks over it while the player still plays it.
    paced = Script(turns=turns, ms_per_char=MS_PER_CHAR, pace=1.0)
    wav = tmp_path / "played.wav"
    with live_graph(ros_namespace, tmp_path, paced, wav=wav) as graph:
        probe, check, api = graph.probe, graph.check, graph.api
        say_live(probe, corpus_utterance(0))
        stream = until(
            lambda: next((s.stream_id for s in list(probe.playback) if s.played_ms >= 500), None),
            "the story playing",
            check,
            WAIT_S,
        )
        say_live(probe, corpus_utterance(1))  # over the story: the model hears it and yields

        interruption = until(lambda: list(probe.interruptions), "the interruption signal", check, WAIT_S)[0]
        assert (interruption.stream_id, interruption.reason, interruption.action) == (
            stream,
            "model_yielded",
            Interruption.CUT,
        )
        cut = until(
            lambda: [s for s in list(probe.playback) if s.stream_id == stream and s.interrupted],
            "the player cut the story",
            check,
            WAIT_S,
        )[0]
        # The next question is answered on the same session, and played whole.
        until(lambda: "It is red." in probe.texts(probe.replies), "the question answered", check, WAIT_S)
        answer = until(
            lambda: [sid for sid in graph.finished_streams() if sid != stream],
            "the answer played",
            check,
            WAIT_S,
        )
        assert stream not in graph.finished_streams()  # the story never played to its end
        assert len(probe.interruptions) == 1 and answer[0] != stream
        [yielded] = api.interruptions()  # the emulator stopped the story part-way
        assert yielded.connection == 0 and 0 < len(yielded.said) < len(story)
        assert story.startswith(yielded.said)
        assert api.connections() == 1
        lines = graph.stop_agent()
        graph.stop_player()
        assert any("the model yielded to the user" in line for line in lines), "\n".join(lines)

    heard, _, _ = read_wav(wav)
    answer_pcm = speech_pcm("It is red.", MS_PER_CHAR)
    whole_story = speech_pcm(story, MS_PER_CHAR)
    played = heard.tobytes()
    assert played.endswith(answer_pcm)
    story_part = played[: len(played) - len(answer_pcm)]
    # A beginning of the story, clearly less than all of it, and what the player reported at the cut.
    assert whole_story.startswith(story_part) and 0 < len(story_part) < len(whole_story) // 2
    assert abs(len(story_part) // 48 - cut.played_ms) <= 100


def commentary_result(commentary: dict[str, object]) -> dict[str, object]:
    """A delegation's result as the agent told the model (provider: a prefix, then the JSON)."""
    content = str(commentary["content"])
    prefix = "Result of the delegated task: "
    assert content.startswith(prefix), content
    result: dict[str, object] = json.loads(content[len(prefix) :])
    return result


def test_a_delegation_of_a_declared_phrase_drives_the_robot_and_other_words_go_to_the_processor(
    ros_namespace: str, tmp_path: Path
) -> None:
    turns = (
        Turn(Delegate(Say("On my way."), then=Say("I am in the kitchen.")), heard="go to the kitchen"),
        Turn(Delegate(Say("One moment.")), heard="please wave"),  # `then` omitted: the result is said
    )
    tools = CONFIG_DIR / "tools_demo.yaml"  # go_to: spoken "go to the {place}", kitchen at (3.0, 1.2)
    with live_graph(
        ros_namespace,
        tmp_path,
        script(*turns),
        processor=True,
        tools=tools,
        robot=("speed_mps:=5.0", "feedback_rate_hz:=10.0"),
    ) as graph:
        probe, check, api = graph.probe, graph.check, graph.api
        probe.activity.publish(Bool(data=True))
        probe.say(corpus_utterance(0))
        probe.activity.publish(Bool(data=False))
        until(
            lambda: "I am in the kitchen." in probe.texts(probe.replies),
            "the reply after arriving",
            check,
            WAIT_S,
        )
        [drive] = api.delegation_ids()
        [commentary] = api.commentaries()
        assert commentary["delegation_id"] == drive
        result = commentary_result(commentary)
        assert result.get("ok") is True and result.get("status") == "succeeded", result
        # The declared place's pose from tools_demo.yaml, not numbers from a model.
        goals = until(graph.robot_goals, "demo_robot's log of the goal", check, WAIT_S)
        assert goals == [(3.0, 1.2, "map")]
        ended = until(
            lambda: [r for r in graph.records("tool_call") if r["state"] != "running"],
            "the tool call's end on agent_metrics",
            check,
            WAIT_S,
        )
        assert [(r["tool"], r["kind"], r["state"]) for r in ended] == [("go_to", "action", "succeeded")]
        assert json.loads(ended[0]["arguments"]) == {"place": "kitchen"}
        assert not probe.requests  # the tool ran: nothing went to the command processor

        # Words that are no declared phrase: a robot_command for the processor, its verdict told back.
        probe.activity.publish(Bool(data=True))
        probe.say(corpus_utterance(1))
        probe.activity.publish(Bool(data=False))
        until(lambda: len(api.commentaries()) == 2, "the second delegation's result", check, WAIT_S)
        wave = api.delegation_ids()[1]
        second = api.commentaries()[1]
        assert second["delegation_id"] == wave
        [request] = until(lambda: list(probe.requests), "the robot_command request", check, WAIT_S)
        assert request.text == "please wave"
        verdict = until(
            lambda: [v for v in list(probe.verdicts) if v.request_id == request.request_id],
            "the processor's verdict",
            check,
            WAIT_S,
        )[0]
        told = commentary_result(second)
        assert (told["accepted"], told["reason"]) == (verdict.accepted, verdict.reason), told
        until(
            lambda: any(str(second["content"]) == text for text in probe.texts(probe.replies)),
            "the verdict said",
            check,
            WAIT_S,
        )
        assert graph.robot_goals() == [(3.0, 1.2, "map")]  # nothing more for the robot
        graph.stop_agent()
