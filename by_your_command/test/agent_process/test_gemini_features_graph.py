"""The Gemini agent's own features in a real ROS graph (issue 11): the installed executables with only
GOOGLE_API_KEY, toolCallCancellation withdrawing a command, object detections on `detections`, a
refused resumption falling back to a fresh session, and a 1011 "Deadline expired" close mid-reply.
ros_ai_bridge and command_processor as processes, the agents through the official google-genai SDK
against the Gemini Live emulator (TLS); helpers in agent_graph.py."""

from __future__ import annotations

import io
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from agent_graph import (
    AgentGraph,
    GeminiEmulatorThread,
    GraphProbe,
    corpus_utterance,
    gemini_emulator,
    gemini_graph,
    until,
)
from builtin_interfaces.msg import Time
from PIL import Image as PilImage
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import Bool, Header, String

from by_your_command.emulators.gemini_script import CallTool, Say, Script, Turn
from by_your_command.emulators.gemini_wire import field_value
from by_your_command.nodes._qos import RELIABLE

pytestmark = [pytest.mark.ros, pytest.mark.timeout(240)]

MS_PER_CHAR = 40  # reply audio per character (emulator): short replies, quick tests
WAIT_S = 90.0  # condition waits: generous, the machine is shared and has 2 cores


def records(graph: AgentGraph, kind: str = "turn") -> list[dict[str, Any]]:
    return [r for r in graph.probe.metric_records() if r["record"] == kind]


def counters(lines: list[str]) -> dict[str, int]:
    """The counters the agent logs when it stops."""
    match = next(m for line in lines if (m := re.search(r"stopped; counters (\{.*\})", line)))
    return {key: int(value) for key, value in re.findall(r"'(\w+)': (\d+)", match.group(1))}


def pcm16(samples: np.ndarray) -> bytes:
    return samples.astype("<i2").tobytes()


def resumed_with(api: GeminiEmulatorThread, connection: int) -> str | None:
    resumption = field_value(api.bodies("setup", connection)[0], "sessionResumption")
    return field_value(resumption, "handle") if resumption is not None else None


def history_sent(api: GeminiEmulatorThread, connection: int) -> list[tuple[str, str]]:
    """(role, text) of the clientContent without turnComplete: a fresh session's text history."""
    return [
        (content.get("role", "user"), " ".join(part["text"] for part in content["parts"]))
        for body in api.bodies("clientContent", connection)
        if not field_value(body, "turnComplete")
        for content in body["turns"]
    ]


def listen(probe: GraphProbe, topic: str, check: Callable[[], None]) -> list[String]:
    """Record a topic the bridge publishes, once DDS matched us with the bridge's publisher (a
    message published before that would be lost: nothing in ROS queues for an unmatched reader)."""
    store: list[String] = []
    subscription = probe.probe.node.create_subscription(String, topic, store.append, RELIABLE)
    until(lambda: subscription.get_publisher_count() > 0, f"the bridge's {topic} publisher", check)
    return store


def jpeg(width: int, height: int) -> bytes:
    out = io.BytesIO()
    PilImage.new("RGB", (width, height), (200, 120, 40)).save(out, format="JPEG")
    return out.getvalue()


def test_the_installed_executables_answer_and_route_with_only_google_api_key(
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
            installed=True,
        ) as graph,
    ):
        probe, check = graph.probe, graph.check
        utterance = corpus_utterance(1)
        probe.say(utterance)
        # Two agents open their first sessions at once: a cold start on a loaded machine is slow.
        verdict = until(lambda: list(probe.verdicts), "the command processor's verdict", check, WAIT_S)[0]
        assert (verdict.raw, verdict.command, verdict.accepted) == ("lookup", "lookup", True)
        until(lambda: probe.texts(probe.arm) == ["lookup"], "lookup routed to arm_preset", check, WAIT_S)
        until(lambda: probe.texts(probe.replies), "the live agent's reply", check, WAIT_S)
        talker, commander = graph.agents
        command_lines, talk_lines = commander.stop(), talker.stop()  # exit 0, the key in no line

        assert probe.texts(probe.replies) == ["Looking up."]
        assert probe.texts(probe.commands) == ["lookup"]
        # Each ran its default config (the agent id in its log lines) and sent the key it was given
        # (the emulator closes a keyless setup with 1008) in the header, never in the URL.
        assert any("[agent:conversation]" in line for line in talk_lines)
        assert any("[agent:command]" in line for line in command_lines)
        for api in (talk_api, command_api):
            assert [h.key_source for h in api.handshakes()] == ["header"]
            assert api.closes() == []
            assert api.audio(0) == pcm16(utterance)
        # One key variable only: neither we nor google-genai warn about another one set too.
        assert not any(
            "set too and ignored" in line or "GEMINI_API_KEY are set" in line
            for line in talk_lines + command_lines
        )


def requested(probe: GraphProbe) -> list[str]:
    return [request.text for request in list(probe.requests)]


def test_a_tool_call_cancelled_when_the_user_speaks_gets_no_result_ever(
    ros_namespace: str, tmp_path: Path
) -> None:
    # The robot has not answered (no command processor: no verdict comes) when the user speaks:
    # the server cancels the waiting call. A command cancelled before it is routed is withheld
    # (test/agents/test_tool_cancellation.py, in virtual time); in a real graph whether the
    # cancellation overtakes the routing is a race, so this test takes the routed case.
    script = Script(
        turns=(
            Turn(CallTool("robot_command", json.dumps({"command": "lookup"}), Say("Looking up."))),
            Turn(Say("Yes?"), heard="hello robot, what do you see?"),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    # The pause that closes the session comes after the verdict deadline: a late "no answer from
    # the robot" for the call would be on the wire before the session's record.
    settings = {"tool_verdict_timeout_s": 2.0, "pause_timeout_s": 3.0}
    with (
        gemini_emulator(script) as api,
        gemini_graph(ros_namespace, tmp_path, [(api, "agent_gemini_tool.yaml", settings)]) as graph,
    ):
        probe, check = graph.probe, graph.check
        probe.type_text("look up please")
        until(lambda: requested(probe) == ["lookup"], "the call's command routed", check, WAIT_S)
        utterance = corpus_utterance(0)
        probe.say(utterance)  # its activityStart makes the server cancel the waiting call
        until(lambda: "Yes?" in probe.texts(probe.replies), "the reply to the utterance", check, WAIT_S)
        until(lambda: records(graph, "session"), "the session closed at the pause", check, WAIT_S)
        turns = records(graph)
        lines = graph.agents[0].stop()

        assert [t["outcome"] for t in turns] == ["cancelled", "completed"]
        assert probe.texts(probe.replies) == ["Yes?"], "no reply, no failure report for the cancelled call"
        # The model never got a result for the withdrawn call: no toolResponse at all.
        steps = api.steps(0)
        assert "toolResponse" not in steps
        assert steps[:2] == ["setup", "clientContent"] and steps[-1] == "activityEnd"
        assert api.audio(0) == pcm16(utterance)
        counted = counters(lines)
        assert [counted[name] for name in ("tool_calls_cancelled", "commands_withheld", "tool_timeouts")] == [
            1,
            0,
            0,
        ]
        assert any("cancelled tool call" in line and "may already act on it" in line for line in lines)


def test_boxes_in_a_reply_go_to_detections_in_the_frames_pixels_and_never_to_the_robot(
    ros_namespace: str, tmp_path: Path
) -> None:
    boxes = '```json\n[{"box_2d": [100, 200, 500, 600], "label": "cup"}]\n```'
    script = Script(turns=(Turn(Say(boxes), heard="where is the cup"), Turn(Say("lookup"))))
    with (
        gemini_emulator(script) as api,
        gemini_graph(
            ros_namespace, tmp_path, [(api, "agent_gemini_command.yaml", {})], processor=True
        ) as graph,
    ):
        probe, check = graph.probe, graph.check
        detections = listen(probe, "detections", check)
        camera = probe.probe.node.create_publisher(CompressedImage, "camera_forwarded", RELIABLE)

        until(
            lambda: probe.bridge_hears(camera, ros_namespace, "camera_forwarded"),
            "the bridge and the camera publisher matched",
            check,
            WAIT_S,
        )
        frame = jpeg(320, 240)  # not square: x and y cannot be swapped unnoticed
        header = Header(stamp=Time(sec=1_800_000_000, nanosec=250_000_000), frame_id="camera_optical")

        # "where is the cup?" with a frame taken while it is asked: the model gets that frame.
        chunks = probe.utterance(corpus_utterance(0))
        for chunk in chunks[:3]:
            probe.voice.publish(chunk)
        camera.publish(CompressedImage(header=header, format="jpeg", data=frame))
        until(lambda: api.frames(), "the frame at the model mid-question", check, WAIT_S)
        for chunk in chunks[3:]:
            probe.voice.publish(chunk)
        until(lambda: detections, "the boxes on detections", check, WAIT_S)
        # Then a command: it is routed, so the processor was listening all along.
        probe.type_text("look up")
        until(lambda: probe.verdicts, "the command's verdict", check, WAIT_S)
        graph.agents[0].stop()

        assert api.frames() == [frame]
        # The shipped command prompt asks for those boxes.
        instruction = field_value(api.bodies("setup")[0], "systemInstruction")
        assert '"box_2d": [ymin, xmin, ymax, xmax]' in " ".join(part["text"] for part in instruction["parts"])
        [report] = [json.loads(message.data) for message in detections]
        assert report == {
            "stamp": 1_800_000_000.25,
            "frame_id": "camera_optical",
            "width": 320,
            "height": 240,
            "agent_id": "command",
            "detections": [
                # [x_min, y_min, x_max, y_max] in pixels: 0-1000 scaled by 320 wide, 240 high
                {
                    "label": "cup",
                    "box": [64.0, 24.0, 192.0, 120.0],
                    "box_2d": [100, 200, 500, 600],
                    "score": None,
                }
            ],
        }
        # The boxes reply was no command: the only thing routed (and judged) is the next reply.
        assert probe.texts(probe.commands) == ["lookup"]
        assert [(v.raw, v.accepted) for v in probe.verdicts] == [("lookup", True)]


def test_a_refused_resumption_starts_a_fresh_session_with_the_text_history(
    ros_namespace: str, tmp_path: Path
) -> None:
    script = Script(
        turns=(
            Turn(Say("I see a door."), heard="hello robot, what do you see?"),
            Turn(Say("It is red."), heard="turn left and look at the door"),
        ),
        ms_per_char=MS_PER_CHAR,
        refuse_resume=True,
    )
    with (
        gemini_emulator(script) as api,
        gemini_graph(
            ros_namespace, tmp_path, [(api, "agent_gemini.yaml", {"pause_timeout_s": 1.0})]
        ) as graph,
    ):
        probe, check = graph.probe, graph.check
        probe.say(corpus_utterance(0))
        until(lambda: probe.texts(probe.replies), "the first reply", check, WAIT_S)
        until(lambda: records(graph, "session"), "the session closed at the pause", check, WAIT_S)
        # The next speech reopens it: the resume is refused, a fresh session carries the history.
        second = corpus_utterance(1)
        probe.activity.publish(Bool(data=True))
        probe.say(second)
        until(
            lambda: "It is red." in probe.texts(probe.replies),
            "the reply in the fresh session",
            check,
            WAIT_S,
        )
        turns = until(lambda: len(records(graph)) >= 2 and records(graph), "turn metrics", check)
        lines = graph.agents[0].stop()

        assert probe.texts(probe.replies) == ["I see a door.", "It is red."]
        assert [t["outcome"] for t in turns] == ["completed", "completed"]
        assert api.connections() == 3
        assert resumed_with(api, 1), "the agent tried to resume with the handle it was given"
        assert [(c.connection, c.code) for c in api.closes()] == [(1, 1007)]
        assert resumed_with(api, 2) is None
        assert history_sent(api, 2) == [("user", "hello robot, what do you see?"), ("model", "I see a door.")]
        assert api.audio(2) == pcm16(second), "the utterance, whole, in the fresh session"
        assert any("refused the resumption" in line for line in lines)


def test_a_deadline_close_mid_reply_fails_that_turn_and_the_next_is_answered_on_a_new_session(
    ros_namespace: str, tmp_path: Path
) -> None:
    story = "Once upon a time there was a robot who loved to talk about everything it saw."
    script = Script(
        turns=(
            Turn(Say(story), close_after_ms=300),
            Turn(Say("Yes?"), heard="hello robot, what do you see?"),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    with (
        gemini_emulator(script) as api,
        gemini_graph(ros_namespace, tmp_path, [(api, "agent_gemini.yaml", {})]) as graph,
    ):
        probe, check = graph.probe, graph.check
        probe.say(corpus_utterance(2))
        failed = until(lambda: records(graph), "the cut turn's record", check, WAIT_S)[0]
        assert failed["outcome"] == "failed"
        second = corpus_utterance(0)
        probe.say(second)
        until(lambda: "Yes?" in probe.texts(probe.replies), "the reply on the new session", check, WAIT_S)
        turns = until(lambda: len(records(graph)) >= 2 and records(graph), "turn metrics", check)
        lines = graph.agents[0].stop()

        assert [t["outcome"] for t in turns] == ["failed", "completed"]
        # The close is reported (logged and counted), not taken for a normal end of the session.
        assert any("server_closed" in line and "(1011 Deadline expired" in line for line in lines)
        assert counters(lines)["provider_errors"] == 1
        assert [t["session"] for t in turns] == [1, 2]
        [close] = api.closes()
        assert (close.connection, close.code) == (0, 1011) and close.reason.startswith("Deadline expired")
        assert api.connections() == 2
        assert api.audio(1) == pcm16(second)
        assert "failed" not in " ".join(probe.texts(probe.replies))  # a report is not the robot's words
        assert turns[0]["reason"].startswith("the provider failed the reply (Gemini closed the session (1011")
