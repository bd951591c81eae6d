"""Session cycling, rotation, provider drops, false interruptions and camera frames, with the agent
as a process in a real ROS graph (ros_ai_bridge, simple_audio_player with a WAV sink) against the
OpenAI emulator through the official SDK: the items of issue 9 that test_agent_graph.py does not
cover. Timing knobs are set with `byc agent --set`, so each test stays short."""

from __future__ import annotations

import base64
import io
import subprocess
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from agent_graph import (
    FAKE_KEY,
    EmulatorThread,
    GraphProbe,
    Output,
    agent_config,
    agent_process,
    alive,
    bridge_process,
    corpus_utterance,
    emulator,
    graph_probe,
    player_process,
    setup_requests,
    stop_agent,
    stop_player,
    until,
)
from by_your_command_msgs.msg import Interruption
from PIL import Image
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import Bool

from by_your_command.audio.pcm import StreamResampler, read_wav
from by_your_command.emulators.openai_script import Say, Script, Turn
from by_your_command.emulators.synthetic_speech import speech_pcm
from by_your_command.nodes._qos import RELIABLE

pytestmark = [pytest.mark.ros, pytest.mark.timeout(180)]

MS_PER_CHAR = 40  # reply audio per character (emulator)
BYTES_PER_MS = 48  # 24 kHz int16 mono


@dataclass
class Graph:
    openai: EmulatorThread
    probe: GraphProbe
    agent: subprocess.Popen[str]
    agent_out: Output
    check: Any
    player: subprocess.Popen[str] | None

    def stop_agent(self) -> list[str]:
        return stop_agent(self.agent, self.agent_out)

    def stop_player(self) -> None:
        assert self.player is not None
        stop_player(self.player)

    def received(self, connection: int) -> list[dict[str, Any]]:
        return [r.event for r in self.openai.received() if r.connection == connection]

    def open_connections(self) -> int:
        return self.openai.open_connections()

    def sessions(self) -> list[dict[str, Any]]:
        return [r for r in self.probe.metric_records() if r["record"] == "session"]

    def turns(self) -> list[dict[str, Any]]:
        return [r for r in self.probe.metric_records() if r["record"] == "turn"]

    def finished_streams(self) -> list[str]:
        return [s.stream_id for s in list(self.probe.playback) if s.finished]


@contextmanager
def agent_graph(
    namespace: str, tmp_path: Path, script: Script, *sets: str, wav: Path | None = None, **settings: Any
) -> Iterator[Graph]:
    """Emulator, probe, (player,) bridge and `byc agent --set ...` for each of `sets`."""
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(namespace))
        player = None
        if wav is not None:
            player = stack.enter_context(player_process(namespace, wav))
            probe.wait_nodes(alive(player), player=True)
        port, _ = stack.enter_context(bridge_process(namespace))
        config, data = agent_config(tmp_path, openai.url, **settings)
        options = [option for value in sets for option in ("--set", value)]
        agent, agent_out = stack.enter_context(agent_process(config, port, FAKE_KEY, *options))
        check = alive(agent, *([player] if player is not None else []))
        probe.wait_agents_ready(namespace, [setup_requests(data)])
        yield Graph(openai, probe, agent, agent_out, check, player)


def user_texts(events: list[dict[str, Any]]) -> list[tuple[str, str]]:
    """(role, text) of the message items a client created, in order."""
    return [
        (event["item"]["role"], part["text"])
        for event in events
        if event["type"] == "conversation.item.create" and event["item"]["type"] == "message"
        for part in event["item"]["content"]
        if part["type"] in ("input_text", "output_text")
    ]


def appended(events: list[dict[str, Any]]) -> bytes:
    return b"".join(base64.b64decode(e["audio"]) for e in events if e["type"] == "input_audio_buffer.append")


def at_24k(pcm: np.ndarray) -> bytes:
    """The utterance as the agent must send it: 16 kHz resampled to the session's 24 kHz."""
    resampler = StreamResampler(16000, 24000)
    return np.concatenate([resampler.push(pcm), resampler.flush()]).astype("<i2").tobytes()


def test_pause_closes_the_session_and_speech_reopens_it_with_the_conversation_and_all_audio(
    ros_namespace: str, tmp_path: Path
) -> None:
    script = Script(
        turns=(
            Turn(Say("I see a door."), heard="what do you see"),
            Turn(Say("It is red."), heard="what colour"),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    wav = tmp_path / "played.wav"
    with agent_graph(ros_namespace, tmp_path, script, "pause_timeout_s=1.0", wav=wav) as graph:
        probe, openai, check = graph.probe, graph.openai, graph.check
        first, second = corpus_utterance(0), corpus_utterance(1)
        probe.say(first)
        until(lambda: graph.finished_streams(), "the first reply played", check)

        # The pause: nothing pending, nothing playing → the agent closes the paid session.
        until(lambda: graph.sessions(), "the session closed and billed", check)
        until(lambda: graph.open_connections() == 0, "the emulator saw the connection close", check)
        [closed] = graph.sessions()
        assert closed["close_reason"] == "pause of 1 s" and closed["turns"] == 1
        assert closed["billed_s"] > 0
        assert openai.connections() == 1

        # The next speech reopens it: all chunks arrive while the new session connects.
        probe.activity.publish(Bool(data=True))
        probe.say(second)
        until(lambda: len(graph.finished_streams()) >= 2, "the reply in the new session played", check)
        assert openai.connections() == 2
        assert probe.texts(probe.replies) == ["I see a door.", "It is red."]
        lines = graph.stop_agent()
        graph.stop_player()

        old, new = graph.received(0), graph.received(1)
        # The earlier conversation is carried as text items before the new turn's audio.
        assert user_texts(new) == [("user", "what do you see"), ("assistant", "I see a door.")]
        types = [e["type"] for e in new]
        history_end = max(k for k, t in enumerate(types) if t == "conversation.item.create")
        assert history_end < types.index("input_audio_buffer.append")
        assert types[0] == "session.update"
        assert new[0]["session"]["instructions"] == old[0]["session"]["instructions"]
        # No audio lost to the reconnect: each session got its utterance whole, sample for sample.
        assert appended(old) == at_24k(first)
        assert appended(new) == at_24k(second)
        assert types.count("input_audio_buffer.commit") == types.count("response.create") == 1
        assert any("session 1 closed (pause of 1 s)" in line for line in lines)

    heard, _, _ = read_wav(wav)
    assert heard.tobytes() == speech_pcm("I see a door.", MS_PER_CHAR) + speech_pcm("It is red.", MS_PER_CHAR)


def test_rotation_before_the_session_limit_happens_between_turns_and_loses_none(
    ros_namespace: str, tmp_path: Path
) -> None:
    # The "provider" ends every session after 8 s; the agent is told its limit and rotates with a
    # 4 s margin. Turns keep coming all the while.
    answers = [f"Answer {k}." for k in range(30)]
    script = Script(turns=tuple(Turn(Say(a)) for a in answers), ms_per_char=MS_PER_CHAR, session_expiry_s=8.0)
    sets = ("max_session_s=8.0", "rotation_margin_s=4.0")
    with agent_graph(ros_namespace, tmp_path, script, *sets, wav=tmp_path / "played.wav") as graph:
        probe, openai, check = graph.probe, graph.openai, graph.check
        asked = 0
        extra = 2  # turns after the rotation, on the new session
        while asked < len(answers) and extra:
            asked += 1
            probe.type_text(f"question {asked}")
            until(lambda n=asked: len(probe.replies) >= n, f"the reply to question {asked}", check)
            until(lambda n=asked: len(graph.finished_streams()) >= n, f"answer {asked} played", check)
            if openai.connections() == 2:
                extra -= 1
        assert openai.connections() == 2 and not extra
        lines = graph.stop_agent()

        # Every turn was answered, in order, none failed or replayed.
        assert probe.texts(probe.replies) == answers[:asked]
        assert [t["outcome"] for t in graph.turns()] == ["completed"] * asked
        first, rotated = graph.sessions()[:2]
        assert first["close_reason"] == "rotation before the limit"
        assert rotated["close_reason"] == "agent stopped"
        assert first["turns"] + rotated["turns"] == asked
        # Closed by the agent before the provider's limit: the provider never ended it.
        troubles = ("session 1 lost", "session_expired", "ending the session", " failed:")
        assert not [line for line in lines if any(word in line for word in troubles)], "\n".join(lines)
        # The rotation fell between turns: each session got whole turns (one reply per request),
        # and the new one started with the conversation so far.
        old, new = graph.received(0), graph.received(1)
        typed = [text for role, text in user_texts(old) if role == "user"]
        assert typed == [f"question {k}" for k in range(1, first["turns"] + 1)]
        assert [e["type"] for e in old].count("response.create") == first["turns"]
        history = [text for role, text in user_texts(new) if role == "user"]
        assert history == [f"question {k}" for k in range(1, asked + 1)]


def test_a_provider_drop_mid_reply_fails_that_turn_and_the_next_turn_works(
    ros_namespace: str, tmp_path: Path
) -> None:
    story = "Once upon a time there was a robot who loved to talk."
    script = Script(
        turns=(Turn(Say(story), drop_after_ms=300), Turn(Say("Second."))), ms_per_char=MS_PER_CHAR
    )
    wav = tmp_path / "played.wav"
    with agent_graph(ros_namespace, tmp_path, script, wav=wav) as graph:
        probe, openai, check = graph.probe, graph.openai, graph.check
        probe.type_text("tell me a story")
        report = until(
            lambda: [t for t in graph.turns() if t["outcome"] == "failed"], "the failed turn reported", check
        )[0]
        assert report["turn"] == 1 and "lost" in report["reason"], report
        until(lambda: graph.open_connections() == 0, "the dropped connection gone", check)
        probe.type_text("are you there")
        until(lambda: "Second." in probe.texts(probe.replies), "the reply on a new session", check)
        until(lambda: graph.finished_streams(), "the second reply played", check)
        assert openai.connections() == 2
        assert [(t["turn"], t["outcome"]) for t in graph.turns()] == [(1, "failed"), (2, "completed")]
        assert graph.sessions()[0]["close_reason"].startswith("failed: ")
        assert probe.texts(probe.replies) == ["Second."]  # the failure is a report, not the robot's words
        graph.stop_agent()
        graph.stop_player()
        # The new session carried the turn that failed as text, and the new turn was answered there.
        new = graph.received(1)
        assert ("user", "tell me a story") in user_texts(new)
        assert user_texts(new)[-1] == ("user", "are you there")

    # The listener heard the 300 ms that came before the drop, then the next reply, whole.
    heard, _, _ = read_wav(wav)
    partial = speech_pcm(story, MS_PER_CHAR)[: 300 * BYTES_PER_MS]
    assert heard.tobytes() == partial + speech_pcm("Second.", MS_PER_CHAR)


def test_a_false_interruption_resumes_the_reply_where_the_listener_lost_it(
    ros_namespace: str, tmp_path: Path
) -> None:
    story = "Once upon a time there was a robot who loved to talk about all it saw."
    script = Script(turns=(Turn(Say(story)),), ms_per_char=MS_PER_CHAR)
    story_pcm = speech_pcm(story, MS_PER_CHAR)
    wav = tmp_path / "played.wav"
    settings = {"echo_mode": "external", "min_barge_in_ms": 400, "barge_in_window_s": 5.0}
    with agent_graph(ros_namespace, tmp_path, script, wav=wav, **settings) as graph:
        probe, openai, check = graph.probe, graph.openai, graph.check
        probe.type_text("tell me a story")

        def story_playing() -> str | None:
            return next((s.stream_id for s in list(probe.playback) if s.played_ms >= 500), None)

        stream = until(story_playing, "500 ms of the story played", check)
        probe.activity.publish(Bool(data=True))  # the VAD heard something over the reply...
        until(
            lambda: [s for s in list(probe.playback) if s.stream_id == stream and s.paused],
            "the player paused the story",
            check,
        )
        # ...but it was a cough: 200 ms of noise, shorter than min_barge_in_ms.
        noise = np.random.default_rng(7).normal(0, 3000, 3200).astype(np.int16)
        probe.say(noise)
        probe.activity.publish(Bool(data=False))

        until(lambda: stream in graph.finished_streams(), "the rest of the story played", check)
        actions = [(i.stream_id, i.action) for i in probe.interruptions]
        assert actions == [(stream, Interruption.PAUSE), (stream, Interruption.RESUME)]
        assert not any(s.interrupted for s in probe.playback)
        lines = graph.stop_agent()
        graph.stop_player()
        # The noise never reached the model, and the model's reply was never cancelled.
        types = openai.types()
        assert "input_audio_buffer.append" not in types
        assert "response.cancel" not in types and "conversation.item.truncate" not in types
        assert probe.texts(probe.replies) == [story]
        assert any("false barge-in" in line and "resumed" in line for line in lines)
        assert [t["outcome"] for t in graph.turns()] == ["completed"]
        # One stream, whose played_ms ran on over the pause: all of the story was heard.
        played = max(s.played_ms for s in probe.playback if s.stream_id == stream)
        assert played == len(story_pcm) // BYTES_PER_MS

    # What the listener heard: the whole story once, nothing skipped and nothing repeated (the
    # block in the device at the pause is played again from its unheard part only).
    heard = read_wav(wav)[0].tobytes()
    assert heard == story_pcm


def jpeg(width: int = 32, height: int = 24) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (width, height), (200, 30, 30)).save(buffer, format="JPEG")
    return buffer.getvalue()


def test_a_camera_frame_goes_to_the_model_with_the_next_turn(ros_namespace: str, tmp_path: Path) -> None:
    script = Script(turns=(Turn(Say("A red block.", modality="auto")),), ms_per_char=MS_PER_CHAR)
    frame = jpeg()
    with agent_graph(ros_namespace, tmp_path, script) as graph:
        probe, openai, check = graph.probe, graph.openai, graph.check
        camera = probe.probe.node.create_publisher(CompressedImage, "camera_forwarded", RELIABLE)
        until(
            lambda: probe.bridge_hears(camera, ros_namespace, "camera_forwarded"),
            "the bridge and the camera publisher matched",
            check,
        )

        def delivered() -> int:
            return int((probe.bridge_values(ros_namespace) or {}).get("ros_messages_delivered", "-1"))

        until(lambda: delivered() >= 0, "bridge diagnostics", check)
        before = delivered()
        camera.publish(CompressedImage(format="jpeg", data=list(frame)))

        def sent_to_the_agent() -> bool:
            values = probe.bridge_values(ros_namespace) or {}
            depth = [v for k, v in values.items() if k.endswith(".queue_depth")]
            return delivered() > before and depth == ["0"]

        until(sent_to_the_agent, "the frame sent to the agent", check)
        assert openai.connections() == 0  # a frame alone never opens a paid session
        probe.type_text("what do you see")
        until(lambda: probe.texts(probe.replies) == ["A red block."], "the reply", check)
        turn = until(lambda: graph.turns(), "turn metrics", check)[0]
        graph.stop_agent()

        events = openai.events("conversation.item.create")
        contents = [part for event in events for part in event["item"]["content"]]
        assert [part["type"] for part in contents] == ["input_image", "input_text"]
        image = contents[0]
        assert image["image_url"] == "data:image/jpeg;base64," + base64.b64encode(frame).decode()
        assert image["detail"] == "low"
        assert turn["usage"]["input_image_tokens"] == script.image_tokens  # billed, and counted
