"""The safety stop through the real path: a microphone stream → silero_vad_node (its stop spotter)
→ ros_ai_bridge → `byc agent` (OpenAI emulator). The user says "stop" to a silent robot: the VAD
routes `stop` itself and names the utterance; the same utterance reaches the agent on
`prompt_voice`, before or after the stop (two topics, no order). Either way the model's answer to
it is never said, and the next question is answered."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import pytest
from agent_graph import (
    agent_config,
    agent_process,
    alive,
    bridge_process,
    emulator,
    graph_probe,
    setup_requests,
    until,
)
from by_your_command_msgs.msg import AudioChunk
from microphone import Microphone, spoken, vad_process

from by_your_command.emulators.openai_script import Say, Script
from by_your_command.nodes._qos import AUDIO_IN

pytestmark = [pytest.mark.ros, pytest.mark.e2e, pytest.mark.timeout(180)]

ANSWER = "It is noon."


def test_a_spoken_stop_is_routed_once_and_the_model_never_answers_it(
    ros_namespace: str, tmp_path: Path
) -> None:
    # Every answer takes its spoken time: the stop arrives while the stop's own (if asked) is made.
    script = Script(default_reply=Say(ANSWER), pace=1.0, ms_per_char=40)
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(ros_namespace))
        vad, vad_out = stack.enter_context(vad_process(ros_namespace, stop_spotter=True, echo_gate=True))
        port, bridge_out = stack.enter_context(bridge_process(ros_namespace))
        stack.callback(lambda: print("--- ros_ai_bridge:", *bridge_out.lines, sep="\n"))
        config, settings = agent_config(tmp_path, openai.url)
        agent, agent_out = stack.enter_context(agent_process(config, port))
        check = alive(agent, vad)
        probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])
        until(
            lambda: all(
                probe.bridge_sources(ros_namespace, name) for name in ("prompt_voice", "safety_stop")
            ),
            "the bridge hearing the VAD",
            check,
        )
        # That is the bridge's side of each match. The VAD's publishers learn of the bridge's
        # subscriptions on their own, often later (here up to ~0.7 s), and DDS drops what a
        # publisher sends before it has matched: a "stop" said at once lost its utterance's first
        # chunk or, on a busy machine, reached the agent neither as an utterance nor as a
        # safety_stop. The VAD counts prompt_voice's subscribers itself (the bridge subscribes it for
        # the agent, just now); the bridge announced its safety_stop subscription before that one
        # (at its start), and each participant's discovery data arrives in order.
        until(
            lambda: vad_out.find(r"prompt_voice subscribers: \d+ -> [1-9]"),
            "the VAD's prompt_voice matched with the bridge (its side)",
            check,
        )
        mic_out = probe.probe.node.create_publisher(AudioChunk, "audio", AUDIO_IN)
        until(lambda: mic_out.get_subscription_count() > 0, "the VAD listening on audio", check)
        mic = stack.enter_context(Microphone(mic_out))

        mic.say(spoken("stop"))
        until(lambda: probe.texts(probe.commands), "the VAD's own stop", check)
        until(
            lambda: agent_out.find(r"safety stop heard") and agent_out.find(r"was the stop"),
            "the agent told of the stop, and its utterance known as the stop's",
            check,
        )
        probe.type_text("what time is it")
        until(lambda: ANSWER in probe.texts(probe.replies), "the next question answered", check)
        assert probe.texts(probe.commands) == ["stop"]  # routed once: by the VAD, not the model too
        assert probe.texts(probe.replies) == [ANSWER]  # said once: nothing of an answer to "stop"

        def outcomes() -> list[str]:
            return [r["outcome"] for r in probe.metric_records() if r["record"] == "turn"]

        until(lambda: "completed" in outcomes(), "the next question's turn record", check)
        assert outcomes() in (["completed"], ["stopped", "completed"])  # the stop's turn: none, or stopped
