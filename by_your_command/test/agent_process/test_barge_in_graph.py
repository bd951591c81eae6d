"""Barge-in through the real path (issue 34): a microphone stream → silero_vad_node (real Silero,
the shipped pre-roll) → ros_ai_bridge → `byc agent` (OpenAI emulator; full duplex, the local
transcriber) → simple_audio_player (real-time WAV sink). A short sound over the reply pauses it and
resumes the same stream; a real question later cuts it, and the model's memory is truncated at
all that was heard of the reply, not at what was heard since the resume. The tests that inject
past the VAD hid that every cough was confirmed by the VAD's own pre-roll."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import pytest
from agent_graph import (
    agent_config,
    agent_process,
    alive,
    bridge_process,
    corpus_utterance,
    emulator,
    graph_probe,
    player_process,
    setup_requests,
    until,
)
from by_your_command_msgs.msg import AudioChunk, Interruption
from microphone import Microphone, spoken, vad_process

from by_your_command.emulators.openai_script import Say, Script, Turn
from by_your_command.nodes._qos import AUDIO_IN

pytestmark = [pytest.mark.ros, pytest.mark.e2e, pytest.mark.timeout(180)]

MS_PER_CHAR = 40


def test_a_cough_resumes_the_reply_and_a_later_question_truncates_at_all_that_was_heard(
    ros_namespace: str, tmp_path: Path
) -> None:
    story = "Once upon a time there was a robot who loved to talk about everything it saw." * 3
    script = Script(turns=(Turn(Say(story)), Turn(Say("Yes?"))), ms_per_char=MS_PER_CHAR)
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(ros_namespace))
        player = stack.enter_context(player_process(ros_namespace, tmp_path / "played.wav"))
        vad, _ = stack.enter_context(vad_process(ros_namespace))
        probe.wait_nodes(alive(player, vad), player=True)
        port, _ = stack.enter_context(bridge_process(ros_namespace))
        # Judged on the speech's length alone here, so that counting the VAD's pre-roll would
        # confirm the cough (test_barge_in.py and bench_barge_in.py cover the words).
        config, settings = agent_config(tmp_path, openai.url, echo_mode="external", min_barge_in_words=0)
        agent, agent_out = stack.enter_context(agent_process(config, port))
        check = alive(agent, player, vad)
        probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])
        mic_out = probe.probe.node.create_publisher(AudioChunk, "audio", AUDIO_IN)
        until(lambda: mic_out.get_subscription_count() > 0, "the VAD listening on audio", check)
        mic = stack.enter_context(Microphone(mic_out))

        probe.type_text("tell me a story")

        def played(stream: str) -> int:
            return max((s.played_ms for s in list(probe.playback) if s.stream_id == stream), default=0)

        stream = until(
            lambda: next((s.stream_id for s in list(probe.playback) if s.played_ms >= 1000), None),
            "a second of the story played",
            check,
        )
        # A cough: Silero hears it (an onset, with 480 ms of pre-roll before it) but it is short.
        mic.say(spoken("ha"))
        until(lambda: any(i.action == Interruption.RESUME for i in probe.interruptions), "the resume", check)
        assert [(i.stream_id, i.action) for i in probe.interruptions] == [
            (stream, Interruption.PAUSE),
            (stream, Interruption.RESUME),
        ]
        resumed_at = played(stream)
        until(lambda: played(stream) >= resumed_at + 1500, "the story went on, on the same stream", check)

        # A real question over the rest of it: paused, then cut where it paused.
        mic.say(corpus_utterance(0))  # "Hello robot, what do you see?"
        cut = until(
            lambda: [s for s in list(probe.playback) if s.stream_id == stream and s.interrupted],
            "the story cut",
            check,
        )[0]
        truncate = until(lambda: openai.events("conversation.item.truncate"), "the truncation", check)[0]
        # All that was heard of the reply, before and after the cough (the player's block is 20 ms).
        assert cut.played_ms >= resumed_at + 1500
        assert cut.played_ms - 40 <= truncate["audio_end_ms"] <= cut.played_ms
        until(lambda: "Yes?" in probe.texts(probe.replies), "the question answered", check)
        actions = [(i.stream_id, i.action) for i in probe.interruptions]
        assert actions[2:] == [(stream, Interruption.PAUSE), (stream, Interruption.CUT)]
        assert not mic.busy()
    lines = agent_out.finish()
    assert any("false barge-in" in line for line in lines)
    assert any("barge-in confirmed" in line for line in lines)
