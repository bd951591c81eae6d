"""The agent process in a real ROS graph: ros_ai_bridge, simple_audio_player (WAV sink) and
command_processor as processes, `byc agent` as a process talking to the OpenAI emulator through the
official SDK, and a probe node standing in for the microphone side (issue 9's graph tests)."""

from __future__ import annotations

import json
import signal
import subprocess
from contextlib import ExitStack
from pathlib import Path

import pytest
from agent_graph import (
    FAKE_KEY,
    Output,
    agent_config,
    agent_process,
    alive,
    bridge_process,
    corpus_utterance,
    emulator,
    graph_probe,
    player_process,
    processor_process,
    setup_requests,
    until,
)
from by_your_command_msgs.msg import Interruption, SafetyStop
from std_msgs.msg import Bool

from by_your_command.audio.pcm import read_wav
from by_your_command.emulators.openai_script import CallTool, Say, Script, Turn
from by_your_command.emulators.synthetic_speech import speech_pcm

pytestmark = [pytest.mark.ros, pytest.mark.timeout(180)]

MS_PER_CHAR = 40  # reply audio per character (emulator): short replies, quick tests


def no_secret_in(*outputs: Output) -> None:
    for output in outputs:
        assert FAKE_KEY not in "\n".join(output.lines), "the API key reached a log line"


def stop_agent(process: subprocess.Popen[str], output: Output) -> list[str]:
    """SIGTERM, as Ctrl-C or `ros2 launch` would: the agent must close its session and exit 0."""
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=30) == 0, str(output)
    return output.finish()


def test_voice_turn_then_text_turn(ros_namespace: str, tmp_path: Path) -> None:
    said, answer = "Hello robot, what do you see?", "I see a door."
    typed, typed_answer = "what time is it", "Time for tea."
    script = Script(turns=(Turn(Say(answer), heard=said), Turn(Say(typed_answer))), ms_per_char=MS_PER_CHAR)
    wav = tmp_path / "played.wav"
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(ros_namespace))
        player = stack.enter_context(player_process(ros_namespace, wav))
        probe.wait_nodes(alive(player), player=True)
        port, bridge_out = stack.enter_context(bridge_process(ros_namespace))
        config, settings = agent_config(tmp_path, openai.url)
        agent, agent_out = stack.enter_context(agent_process(config, port))
        check = alive(agent, player)
        probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])

        # (a) a voice turn: streamed, committed, answered; the reply is heard
        utterance = corpus_utterance(0)
        probe.say(utterance)
        until(lambda: probe.texts(probe.replies), "response_text", check)
        until(lambda: any(s.finished for s in list(probe.playback)), "the reply played to its end", check)
        assert probe.texts(probe.transcripts) == [said]
        assert probe.texts(probe.replies) == [answer]
        types = openai.types()
        first_append = types.index("input_audio_buffer.append")
        assert first_append < types.index("input_audio_buffer.commit") < types.index("response.create")
        utterance_ms = 1000 * len(utterance) / 16000  # resampled to 24 kHz, not a sample lost
        assert abs(openai.appended_ms() - utterance_ms) <= 5
        stream_id = next(s.stream_id for s in probe.playback if s.finished)
        assert stream_id.startswith("talker-")
        turn = until(
            lambda: [r for r in probe.metric_records() if r["record"] == "turn"], "turn metrics", check
        )[0]
        assert turn["outcome"] == "completed" and turn["turn_kind"] == "voice"
        assert turn["first_audio_ms"] is not None and turn["first_audio_ms"] <= turn["reply_ms"]

        # (b) a typed turn gets a reply too (the earlier agent's text prompts went unanswered)
        probe.type_text(typed)
        until(lambda: len(probe.replies) >= 2, "the typed turn's reply", check)
        assert probe.texts(probe.replies) == [answer, typed_answer]
        assert probe.texts(probe.transcripts) == [said, typed]
        user_texts = [
            part["text"]
            for event in openai.events("conversation.item.create")
            for part in event["item"].get("content", [])
            if part.get("type") == "input_text"
        ]
        assert user_texts == [typed]
        assert openai.types().count("response.create") == 2
        until(lambda: sum(s.finished for s in list(probe.playback)) >= 2, "the second reply played", check)

        # Ctrl-C: the session is closed and billed, and the agent exits 0
        lines = stop_agent(agent, agent_out)
        assert any("session 1 closed (agent stopped)" in line and "billed" in line for line in lines)
        assert any("stopped; counters" in line for line in lines)
        player.send_signal(signal.SIGTERM)
        player.wait(timeout=30)
        no_secret_in(agent_out, bridge_out)

    heard, rate, _ = read_wav(wav)
    expected = [speech_pcm(text, MS_PER_CHAR) for text in (answer, typed_answer)]
    assert rate == 24000
    assert heard.tobytes() == b"".join(expected), "the player's WAV holds exactly both replies"


def test_dual_agents_the_command_agent_commands_and_the_processor_routes(
    ros_namespace: str, tmp_path: Path
) -> None:
    talk = Script(turns=(Turn(Say("Looking up."), heard="look up"),), ms_per_char=MS_PER_CHAR)
    command = Script(turns=(Turn(Say("lookup"), heard="look up"),))
    with ExitStack() as stack:
        talk_api = stack.enter_context(emulator(talk))
        command_api = stack.enter_context(emulator(command))
        probe = stack.enter_context(graph_probe(ros_namespace))
        processor = stack.enter_context(processor_process(ros_namespace))
        probe.wait_nodes(alive(processor), processor=True)
        port, _ = stack.enter_context(bridge_process(ros_namespace))
        talker_file, talker = agent_config(tmp_path, talk_api.url, "talker")
        commander_file, commander = agent_config(
            tmp_path, command_api.url, "commander", role="command", context_source="shared",
            prompt_id="command_extractor",
        )  # fmt: skip
        talker_proc, talker_out = stack.enter_context(agent_process(talker_file, port))
        commander_proc, commander_out = stack.enter_context(agent_process(commander_file, port))
        check = alive(talker_proc, commander_proc, processor)
        probe.wait_agents_ready(ros_namespace, [setup_requests(talker), setup_requests(commander)])

        probe.say(corpus_utterance(1))
        # Generous: two agents open their first sessions at once (a cold start on a loaded machine
        # may need a connect retry, which the runtime does by itself).
        verdict = until(lambda: list(probe.verdicts), "the command processor's verdict", check, 90)[0]
        assert (verdict.raw, verdict.command, verdict.accepted) == ("lookup", "lookup", True)
        assert verdict.topic == f"{ros_namespace}/arm_preset"
        until(lambda: probe.texts(probe.arm) == ["lookup"], "lookup routed to arm_preset", check)
        until(lambda: probe.texts(probe.replies), "the conversation agent's reply", check)

        # Each agent did its own job: the talker speaks and owns the transcript, the commander
        # asked for text only and published nothing but the command.
        assert probe.texts(probe.commands) == ["lookup"]
        assert probe.texts(probe.replies) == ["Looking up."]
        assert probe.texts(probe.transcripts) == ["look up"]
        talk_session = talk_api.events("session.update")[0]["session"]
        command_session = command_api.events("session.update")[0]["session"]
        assert talk_session["output_modalities"] == ["audio"]
        assert command_session["output_modalities"] == ["text"]
        assert "input_audio_buffer.commit" in command_api.types()  # it heard the same utterance
        assert all(not s.stream_id.startswith("commander") for s in probe.playback)
        stop_agent(commander_proc, commander_out)
        stop_agent(talker_proc, talker_out)
        no_secret_in(talker_out, commander_out)


def test_tool_mode_returns_the_processors_verdicts_to_the_model(ros_namespace: str, tmp_path: Path) -> None:
    script = Script(
        turns=(
            Turn(CallTool("robot_command", json.dumps({"command": "lookup"}), Say("Looking up."))),
            Turn(CallTool("robot_command", json.dumps({"command": "fly@moon"}), Say("I cannot fly."))),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(ros_namespace))
        processor = stack.enter_context(processor_process(ros_namespace))
        probe.wait_nodes(alive(processor), processor=True)
        port, _ = stack.enter_context(bridge_process(ros_namespace))
        config, settings = agent_config(tmp_path, openai.url, "robot", role="tools")
        agent, agent_out = stack.enter_context(agent_process(config, port))
        check = alive(agent, processor)
        probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])

        probe.type_text("look up please")
        until(lambda: probe.texts(probe.replies) == ["Looking up."], "the reply after the tool call", check)
        probe.type_text("fly to the moon")
        until(lambda: len(probe.replies) >= 2, "the reply after the refused call", check)

        tools = openai.events("session.update")[0]["session"]["tools"]
        assert [tool["name"] for tool in tools] == ["robot_command"]
        outputs = [
            json.loads(event["item"]["output"])
            for event in openai.events("conversation.item.create")
            if event["item"]["type"] == "function_call_output"
        ]
        assert len(outputs) == 2
        assert outputs[0] == {"accepted": True, "command": "lookup", "reason": outputs[0]["reason"]}
        assert outputs[0]["reason"] == probe.verdicts[0].reason  # the processor's words, passed on
        assert outputs[1]["accepted"] is False and "unknown" in outputs[1]["reason"]
        assert [(v.raw, v.accepted) for v in probe.verdicts] == [("lookup", True), ("fly@moon", False)]
        assert probe.texts(probe.replies) == ["Looking up.", "I cannot fly."]
        assert probe.texts(probe.arm) == ["lookup"]
        stop_agent(agent, agent_out)
        no_secret_in(agent_out)


def test_barge_in_pauses_the_player_then_cuts_and_truncates_at_what_was_heard(
    ros_namespace: str, tmp_path: Path
) -> None:
    story = "Once upon a time there was a robot who loved to talk about everything it saw." * 2
    script = Script(turns=(Turn(Say(story)), Turn(Say("Yes?"))), ms_per_char=MS_PER_CHAR)
    story_ms = len(story) * MS_PER_CHAR
    wav = tmp_path / "played.wav"
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(ros_namespace))
        player = stack.enter_context(player_process(ros_namespace, wav))
        probe.wait_nodes(alive(player), player=True)
        port, _ = stack.enter_context(bridge_process(ros_namespace))
        config, settings = agent_config(
            tmp_path, openai.url, echo_mode="external", min_barge_in_ms=300, barge_in_window_s=3.0
        )
        agent, agent_out = stack.enter_context(agent_process(config, port))
        check = alive(agent, player)
        probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])

        probe.type_text("tell me a story")

        def story_playing() -> str | None:
            return next((s.stream_id for s in list(probe.playback) if s.played_ms >= 600), None)

        stream_id = until(story_playing, "600 ms of the story played", check)

        # The user starts talking over it: the VAD's onset first, then the utterance's chunks.
        probe.activity.publish(Bool(data=True))
        paused = until(
            lambda: [s for s in list(probe.playback) if s.stream_id == stream_id and s.paused],
            "the player paused the story",
            check,
        )
        frozen_ms = paused[0].played_ms
        assert 600 <= frozen_ms < story_ms
        probe.say(corpus_utterance(0))  # "Hello robot, what do you see?": words, not a backchannel
        probe.activity.publish(Bool(data=False))
        cut = until(
            lambda: [s for s in list(probe.playback) if s.stream_id == stream_id and s.interrupted],
            "the player cut the story",
            check,
        )
        assert cut[0].played_ms == frozen_ms  # nothing more was heard while the speech was judged
        actions = [(i.stream_id, i.action) for i in probe.interruptions]
        assert actions == [(stream_id, Interruption.PAUSE), (stream_id, Interruption.CUT)]

        truncate = until(lambda: openai.events("conversation.item.truncate"), "the truncation", check)[0]
        types = openai.types()
        assert types.index("response.cancel") < types.index("conversation.item.truncate")
        assert truncate["audio_end_ms"] <= story_ms  # never beyond the audio the model produced
        assert frozen_ms - 100 <= truncate["audio_end_ms"] <= frozen_ms  # what the listener heard
        assert truncate["content_index"] == 0
        # The barge-in was a real turn: its audio went to the model and got the reply.
        until(lambda: "Yes?" in probe.texts(probe.replies), "the reply to the interrupting turn", check)
        until(
            lambda: any(s.finished and s.stream_id != stream_id for s in list(probe.playback)),
            "Yes? played",
            check,
        )
        assert all(
            s.played_ms == frozen_ms for s in probe.playback if s.stream_id == stream_id and s.interrupted
        )
        lines = stop_agent(agent, agent_out)
        assert any("barge-in confirmed" in line for line in lines)
        no_secret_in(agent_out)


def test_a_stop_the_model_was_already_answering_is_neither_said_nor_kept(
    ros_namespace: str, tmp_path: Path
) -> None:
    """The VAD's end marker usually reaches the agent before its spotter's `safety_stop` (two
    topics): the model is already answering "stop" when the stop names that utterance. What it
    says to it is dropped, its session closed, and the next question goes to a new session whose
    history holds the stop as a note."""
    stopping, answer = "Okay, I am stopping now, as you asked me to.", "It is noon."
    script = Script(
        turns=(Turn(Say(stopping), heard="stop"),),
        default_reply=Say(answer),
        pace=1.0,  # the reply takes its spoken time: the stop comes while it is being made
        ms_per_char=MS_PER_CHAR,
    )
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        port, _ = stack.enter_context(bridge_process(ros_namespace))
        probe = stack.enter_context(graph_probe(ros_namespace))
        config, settings = agent_config(tmp_path, openai.url)
        agent, _ = stack.enter_context(agent_process(config, port))
        check = alive(agent)
        probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])

        [*chunks, end] = probe.utterance(corpus_utterance(0))
        for chunk in chunks + [end]:
            probe.voice.publish(chunk)
        until(lambda: "response.create" in openai.types(), "the stop's turn committed", check)
        probe.safety_stop.publish(SafetyStop(phrase="stop", utterance_id=end.utterance_id))
        outcome = until(
            lambda: [r["outcome"] for r in probe.metric_records() if r["record"] == "turn"],
            "the stop's turn record",
            check,
        )
        assert outcome == ["stopped"]
        until(lambda: openai.open_connections() == 0, "the stop's session closed", check)

        probe.say(corpus_utterance(1))
        until(lambda: probe.texts(probe.replies), "the next question's reply", check)
        assert probe.texts(probe.replies) == [answer]  # nothing of what it began to say to "stop"
        assert openai.connections() == 2
        notes = [
            part["text"]
            for event in openai.events("conversation.item.create")
            for part in event["item"].get("content", [])
            if "text" in part
        ]
        assert any('"stop" (the robot heard this itself' in note for note in notes)


def test_the_agent_reconnects_after_a_bridge_restart(ros_namespace: str, tmp_path: Path) -> None:
    script = Script(turns=(Turn(Say("First.")), Turn(Say("Second."))), ms_per_char=MS_PER_CHAR)
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(ros_namespace))
        with bridge_process(ros_namespace) as (port, _):
            config, settings = agent_config(tmp_path, openai.url)
            agent, agent_out = stack.enter_context(agent_process(config, port))
            check = alive(agent)
            probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])
            probe.type_text("one")
            until(lambda: probe.texts(probe.replies) == ["First."], "the first reply", check)
        until(lambda: probe.text.get_subscription_count() == 0, "the old bridge gone from the graph", check)
        probe.diagnostics.clear()
        with bridge_process(ros_namespace, port=port):
            probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])
            probe.type_text("two")
            until(
                lambda: probe.texts(probe.replies) == ["First.", "Second."],
                "the reply after the restart",
                check,
            )
            assert agent_out.find(r"connected to ws://127\.0\.0\.1:\d+ \(connection 2\)")
            assert openai.connections() == 1  # the provider session was never at stake
            stop_agent(agent, agent_out)
        no_secret_in(agent_out)


def test_a_refused_api_key_stops_the_agent_with_one_clear_line(ros_namespace: str, tmp_path: Path) -> None:
    script = Script(rejected_api_keys=(FAKE_KEY,))
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        port, _ = stack.enter_context(bridge_process(ros_namespace))
        probe = stack.enter_context(graph_probe(ros_namespace))
        config, settings = agent_config(tmp_path, openai.url)
        # --verbose: not even debug logging may show the key
        agent, agent_out = stack.enter_context(agent_process(config, port, FAKE_KEY, "--verbose"))
        probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])
        probe.type_text("hello?")
        assert agent.wait(timeout=60) == 1
        lines = agent_out.finish()
    errors = [line for line in lines if " ERROR " in line or "Traceback" in line]
    assert len(errors) == 1, "\n".join(lines)
    assert "OpenAI refused the API key" in errors[0] and "OPENAI_API_KEY" in errors[0]
    assert FAKE_KEY not in "\n".join(lines) and FAKE_KEY[-4:] not in "\n".join(lines)
