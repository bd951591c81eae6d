"""The Gemini agent as a process in a real ROS graph (issue 11): ros_ai_bridge, simple_audio_player
(WAV sink), command_processor and frame_forwarder as processes, `byc agent --config agent_gemini*.yaml`
talking through the official google-genai SDK to the Gemini Live emulator (TLS, its own certificate),
and a probe node standing in for the microphone and the camera."""

from __future__ import annotations

import io
import json
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
from by_your_command_msgs.msg import Interruption
from PIL import Image as PilImage
from sensor_msgs.msg import Image
from std_msgs.msg import Bool

from by_your_command.audio.pcm import read_wav
from by_your_command.emulators.gemini_script import CallTool, Say, Script, Turn
from by_your_command.emulators.gemini_wire import field_value
from by_your_command.emulators.synthetic_speech import speech_pcm
from by_your_command.nodes._qos import RELIABLE

pytestmark = [pytest.mark.ros, pytest.mark.timeout(240)]

MS_PER_CHAR = 40  # reply audio per character (emulator): short replies, quick tests
WAIT_S = 90.0  # condition waits: generous, the machine is shared and has 2 cores
RED, BLUE = (220, 20, 20), (20, 20, 220)


def turns(graph: AgentGraph) -> list[dict[str, Any]]:
    return [r for r in graph.probe.metric_records() if r["record"] == "turn"]


def pcm16(samples: np.ndarray) -> bytes:
    return samples.astype("<i2").tobytes()


def setup_of(api: GeminiEmulatorThread, connection: int = 0) -> dict[str, Any]:
    return api.bodies("setup", connection)[0]


def turn_steps(steps: list[str]) -> list[list[str]]:
    """The realtime steps between each activityStart and its activityEnd, one list per activity."""
    out: list[list[str]] = []
    for step in steps:
        if step == "activityStart":
            out.append([])
        elif out and (not out[-1] or out[-1][-1] != "activityEnd"):
            out[-1].append(step)
    return out


def camera_frame(colour: tuple[int, int, int], width: int = 64, height: int = 48) -> Image:
    """A solid-colour rgb8 frame, as a camera driver publishes it."""
    pixels = np.tile(np.array(colour, dtype=np.uint8), (height, width, 1))
    return Image(width=width, height=height, encoding="rgb8", step=width * 3, data=pixels.tobytes())


def colour_of(jpeg: bytes) -> tuple[int, ...]:
    with PilImage.open(io.BytesIO(jpeg)) as image:
        assert image.format == "JPEG"
        pixels = np.asarray(image.convert("RGB"), dtype=float)
    return tuple(int(round(v)) for v in pixels.reshape(-1, 3).mean(axis=0))


def near(colour: tuple[int, ...], expected: tuple[int, int, int]) -> bool:
    return all(abs(a - b) <= 12 for a, b in zip(colour, expected, strict=True))


def test_voice_text_and_what_do_you_see_with_the_frame_taken_after_the_question(
    ros_namespace: str, tmp_path: Path
) -> None:
    script = Script(
        turns=(
            Turn(Say("Hello there."), heard="go to sleep"),
            Turn(Say("Time for tea.")),
            Turn(Say("A red block."), heard="hello robot, what do you see?"),
            Turn(Say("A blue block."), heard="pick up the red block please"),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    answers = ["Hello there.", "Time for tea.", "A red block.", "A blue block."]
    wav = tmp_path / "played.wav"
    # Triggers only (no baseline rate), and a long wait for a frame after a trigger: on a loaded
    # machine the frame published after the question started must still be the one forwarded.
    forwarder = ("max_video_fps:=0.0", "trigger_wait_ms:=20000", "max_frame_age_ms:=20000")
    with (
        gemini_emulator(script) as api,
        gemini_graph(
            ros_namespace, tmp_path, [(api, "agent_gemini.yaml", {})], wav=wav, forwarder=forwarder
        ) as graph,
    ):
        probe, check = graph.probe, graph.check
        camera = probe.probe.node.create_publisher(Image, "camera/image_raw", RELIABLE)

        def played(count: int) -> None:
            """Until `count` replies played to their end (the next reply would cut one still playing)."""
            until(
                lambda: sum(s.finished for s in list(probe.playback)) >= count,
                f"{count} replies played",
                check,
                WAIT_S,
            )

        # (a) a voice turn: one activity around all of the utterance's audio, 16 kHz as spoken
        utterance = corpus_utterance(2)
        probe.say(utterance)
        until(lambda: probe.texts(probe.replies), "the voice turn's reply", check, WAIT_S)
        played(1)
        assert probe.texts(probe.transcripts) == ["go to sleep"]
        assert probe.texts(probe.replies) == answers[:1]
        assert api.steps(0)[:2] == ["setup", "activityStart"]
        assert turn_steps(api.steps(0)) == [["audio"] * (len(api.steps(0)) - 3) + ["activityEnd"]]
        assert api.audio(0) == pcm16(utterance), "not a sample lost or changed (16 kHz in)"
        setup = setup_of(api)
        realtime_config = field_value(setup, "realtimeInputConfig")
        assert field_value(field_value(realtime_config, "automaticActivityDetection"), "disabled") is True
        assert field_value(field_value(setup, "generationConfig"), "responseModalities") == ["AUDIO"]
        assert [h.api_version for h in api.handshakes()] == ["v1beta"]

        # (b) a typed turn: clientContent with turnComplete, answered
        probe.type_text("what time is it")
        until(lambda: len(probe.replies) >= 2, "the typed turn's reply", check, WAIT_S)
        played(2)
        [typed] = [body for body in api.bodies("clientContent") if field_value(body, "turnComplete")]
        assert [part["text"] for part in typed["turns"][0]["parts"]] == ["what time is it"]
        assert probe.texts(probe.transcripts) == ["go to sleep", "what time is it"]

        # (c) "what do you see?": the frame the camera takes after the question started is the
        # one the model gets, while the question is still open.
        def ask_while_the_camera_shoots(pcm: np.ndarray, colour: tuple[int, int, int], seen: int) -> None:
            chunks = probe.utterance(pcm)
            probe.activity.publish(Bool(data=True))  # the frame forwarder's trigger
            for chunk in chunks[:3]:
                probe.voice.publish(chunk)
            camera.publish(camera_frame(colour))

            def at_the_model() -> bool:
                if len(api.frames()) > seen:
                    return True
                # The camera subscription is best effort, and the forwarder's side of the match
                # can come later than ours: shoot again (still after the question started).
                camera.publish(camera_frame(colour))
                return False

            until(at_the_model, "the new frame at the model mid-question", check, WAIT_S)
            for chunk in chunks[3:]:
                probe.voice.publish(chunk)
            probe.activity.publish(Bool(data=False))

        def camera_to_bridge() -> bool:
            # The forwarder's side of the camera match is covered by shooting again (below).
            forwarder_matched = camera.get_subscription_count() > 0
            return forwarder_matched and probe.bridge_sources(ros_namespace, "camera_forwarded") > 0

        until(camera_to_bridge, "the camera, the frame forwarder and the bridge matched", check, WAIT_S)
        ask_while_the_camera_shoots(corpus_utterance(0), RED, 0)
        until(lambda: len(probe.replies) >= 3, "the answer about the red frame", check, WAIT_S)
        played(3)
        ask_while_the_camera_shoots(corpus_utterance(3), BLUE, 1)
        until(lambda: len(probe.replies) >= 4, "the answer about the blue frame", check, WAIT_S)
        played(4)
        records = until(lambda: len(turns(graph)) >= 4 and turns(graph), "turn metrics", check)
        lines = graph.agents[0].stop()

        assert probe.texts(probe.replies) == answers
        frames = api.frames()
        assert len(frames) == 2 and frames[0] != frames[1], "each frame once, none twice"
        assert near(colour_of(frames[0]), RED) and near(colour_of(frames[1]), BLUE)
        # Each frame went inside the activity of the question it belongs to.
        activities = turn_steps(api.steps(0))
        assert [activity.count("video") for activity in activities] == [0, 1, 1]
        assert all(activity[-1] == "activityEnd" for activity in activities)
        assert api.audio_outside_activity_ms() == 0
        assert [r["outcome"] for r in records] == ["completed"] * 4
        assert [r["turn_kind"] for r in records] == ["voice", "text", "voice", "voice"]
        assert records[2]["usage"]["input_image_tokens"] == script.image_tokens  # the frame, billed
        assert any("session 1 closed (agent stopped)" in line for line in lines)
        assert api.connections() == 1

    heard, rate, _ = read_wav(wav)
    assert rate == 24000
    assert heard.tobytes() == b"".join(speech_pcm(a, MS_PER_CHAR) for a in answers), "all heard, whole"


def test_barge_in_the_player_is_paused_before_the_model_is_told_and_the_interrupting_turn_is_answered(
    ros_namespace: str, tmp_path: Path
) -> None:
    story = "Once upon a time there was a robot who loved to talk about everything it saw." * 2
    # pace 1: the story is generated in real time, so it is still being generated when the user
    # cuts in, and the server answers the activityStart with `interrupted`.
    script = Script(
        turns=(Turn(Say(story)), Turn(Say("Yes?"), heard="hello robot, what do you see?")),
        ms_per_char=MS_PER_CHAR,
        pace=1.0,
    )
    wav = tmp_path / "played.wav"
    settings = {"echo_mode": "external", "min_barge_in_ms": 300, "barge_in_window_s": 3.0}
    with (
        gemini_emulator(script) as api,
        gemini_graph(ros_namespace, tmp_path, [(api, "agent_gemini.yaml", settings)], wav=wav) as graph,
    ):
        probe, check = graph.probe, graph.check
        probe.type_text("tell me a story")

        def story_playing() -> str | None:
            return next((s.stream_id for s in list(probe.playback) if s.played_ms >= 600), None)

        stream_id = until(story_playing, "600 ms of the story played", check, WAIT_S)
        probe.activity.publish(Bool(data=True))  # the user starts talking over it
        paused = until(
            lambda: [s for s in list(probe.playback) if s.stream_id == stream_id and s.paused],
            "the player paused the story",
            check,
            WAIT_S,
        )
        # Silence came first: before the model was told (no activityStart yet: the barge-in is
        # not even confirmed) and before any transcript of the cut reply.
        assert "activityStart" not in api.steps(0)
        assert probe.texts(probe.replies) == []
        assert [(i.stream_id, i.action) for i in probe.interruptions] == [(stream_id, Interruption.PAUSE)]
        frozen_ms = paused[0].played_ms
        utterance = corpus_utterance(0)
        probe.say(utterance)
        probe.activity.publish(Bool(data=False))
        until(
            lambda: [s for s in list(probe.playback) if s.stream_id == stream_id and s.interrupted],
            "the player cut the story",
            check,
            WAIT_S,
        )

        until(
            lambda: "Yes?" in probe.texts(probe.replies), "the reply to the interrupting turn", check, WAIT_S
        )
        until(
            lambda: any(s.finished and s.stream_id != stream_id for s in list(probe.playback)),
            "Yes? played",
            check,
            WAIT_S,
        )
        records = until(lambda: len(turns(graph)) >= 2 and turns(graph), "turn metrics", check)
        lines = graph.agents[0].stop()

        # One activity: opened by the interruption, the held utterance in it, then its end.
        steps = api.steps(0)
        assert steps[:2] == ["setup", "clientContent"]
        assert steps.count("activityStart") == 1 and steps.count("activityEnd") == 1
        assert turn_steps(steps) == [["audio"] * steps.count("audio") + ["activityEnd"]]
        assert api.audio(0) == pcm16(utterance), "the held audio, all of it, after the interruption"
        # The cut reply's transcript is what was generated before the cut: a part of the story.
        cut_words, answer = probe.texts(probe.replies)
        assert answer == "Yes?"
        assert cut_words and story.startswith(cut_words) and len(cut_words) < len(story)
        assert [r["outcome"] for r in records] == ["interrupted", "completed"]
        assert any("barge-in confirmed" in line for line in lines)
        assert all(
            s.played_ms == frozen_ms for s in probe.playback if s.stream_id == stream_id and s.interrupted
        )

    # The listener heard the story up to the cut, then the answer, whole: no story audio after
    # the cut (the server's later chunks and its `interrupted` were never played).
    heard = read_wav(wav)[0].tobytes()
    story_pcm, yes = speech_pcm(story, MS_PER_CHAR), speech_pcm("Yes?", MS_PER_CHAR)
    assert heard.endswith(yes)
    story_heard = heard[: len(heard) - len(yes)]
    assert story_heard == story_pcm[: len(story_heard)], "the story's beginning, as generated"
    block = 20 * 48  # the player writes whole 20 ms blocks; played_ms is what it reported
    assert abs(len(story_heard) - frozen_ms * 48) <= block, (len(story_heard) / 48, frozen_ms)


def test_dual_gemini_agents_the_command_agent_text_is_routed_by_the_processor(
    ros_namespace: str, tmp_path: Path
) -> None:
    talk = Script(turns=(Turn(Say("Looking up."), heard="look up"),), ms_per_char=MS_PER_CHAR)
    command = Script(turns=(Turn(Say("lookup"), heard="look up"),))
    with (
        gemini_emulator(talk) as talk_api,
        gemini_emulator(command) as command_api,
        gemini_graph(
            ros_namespace,
            tmp_path,
            [(talk_api, "agent_gemini.yaml", {}), (command_api, "agent_gemini_command.yaml", {})],
            processor=True,
        ) as graph,
    ):
        probe, check = graph.probe, graph.check
        probe.say(corpus_utterance(1))
        # Two agents open their first sessions at once: a cold start on a loaded machine is slow.
        verdict = until(lambda: list(probe.verdicts), "the command processor's verdict", check, WAIT_S)[0]
        assert (verdict.raw, verdict.command, verdict.accepted) == ("lookup", "lookup", True)
        assert verdict.topic == f"{ros_namespace}/arm_preset"
        until(lambda: probe.texts(probe.arm) == ["lookup"], "lookup routed to arm_preset", check, WAIT_S)
        until(lambda: probe.texts(probe.replies), "the conversation agent's reply", check, WAIT_S)
        talker, commander = graph.agents
        commander.stop()
        talker.stop()

        # Each did its own job: the talker speaks and owns the transcript; the command agent's
        # text (the output transcription of an audio-only model) went to response_cmd only.
        assert probe.texts(probe.commands) == ["lookup"]
        assert probe.texts(probe.replies) == ["Looking up."]
        assert probe.texts(probe.transcripts) == ["look up"]
        assert all(s.stream_id.startswith("conversation-") for s in probe.playback)
        assert probe.interruptions == []
        command_setup = setup_of(command_api)
        assert field_value(field_value(command_setup, "generationConfig"), "responseModalities") == ["AUDIO"]
        assert field_value(command_setup, "outputAudioTranscription") is not None
        assert field_value(setup_of(talk_api), "outputAudioTranscription") is not None
        # Both heard the same utterance, in one activity each.
        assert command_api.audio(0) == talk_api.audio(0) == pcm16(corpus_utterance(1))


def test_tool_mode_returns_the_processors_verdicts_to_the_model(ros_namespace: str, tmp_path: Path) -> None:
    script = Script(
        turns=(
            Turn(CallTool("robot_command", json.dumps({"command": "lookup"}), Say("Looking up."))),
            Turn(CallTool("robot_command", json.dumps({"command": "fly@moon"}), Say("I cannot fly."))),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    with (
        gemini_emulator(script) as api,
        gemini_graph(ros_namespace, tmp_path, [(api, "agent_gemini_tool.yaml", {})], processor=True) as graph,
    ):
        probe, check = graph.probe, graph.check
        probe.type_text("look up please")
        until(
            lambda: probe.texts(probe.replies) == ["Looking up."],
            "the reply after the tool call",
            check,
            WAIT_S,
        )
        probe.type_text("fly to the moon")
        until(lambda: len(probe.replies) >= 2, "the reply after the refused call", check, WAIT_S)
        records = until(lambda: len(turns(graph)) >= 2 and turns(graph), "turn metrics", check)
        graph.agents[0].stop()

        tools = field_value(setup_of(api), "tools")
        [declaration] = [d for tool in tools for d in field_value(tool, "functionDeclarations")]
        assert declaration["name"] == "robot_command" and declaration["behavior"] == "BLOCKING"
        responses = [
            response
            for body in api.bodies("toolResponse")
            for response in field_value(body, "functionResponses")
        ]
        assert len(responses) == 2
        first, second = (response["response"] for response in responses)
        assert first == {"accepted": True, "command": "lookup", "reason": probe.verdicts[0].reason}
        assert second["accepted"] is False and "unknown" in second["reason"]
        assert [(v.raw, v.accepted) for v in probe.verdicts] == [("lookup", True), ("fly@moon", False)]
        assert probe.texts(probe.replies) == ["Looking up.", "I cannot fly."]
        assert probe.texts(probe.arm) == ["lookup"]
        assert [r["outcome"] for r in records] == ["completed", "completed"]
        # Each toolResponse answered the call the model made, by id, after the verdict came.
        steps = api.steps(0)
        assert steps == ["setup", "clientContent", "toolResponse", "clientContent", "toolResponse"]
