"""Barge-in through the real path (issue 34): a microphone stream → silero_vad_node (real Silero,
the shipped pre-roll) → ros_ai_bridge → `byc agent` (OpenAI emulator; full duplex, the local
transcriber) → simple_audio_player (real-time WAV sink). A short sound over the reply pauses it and
resumes the same stream, and so does a backchannel the agent's recogniser hears as one; a real
question later cuts it, and the model's memory is truncated at all that was heard of the reply,
not at what was heard since the resume. The tests that inject
past the VAD hid that every cough was confirmed by the VAD's own pre-roll."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from agent_graph import (
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
    until,
)
from by_your_command_msgs.msg import AudioChunk, Interruption
from microphone import Microphone, spoken, vad_process

from by_your_command.agents.config import AgentConfig
from by_your_command.emulators.openai_script import Say, Script, Turn
from by_your_command.nodes._qos import AUDIO_IN

pytestmark = [pytest.mark.ros, pytest.mark.e2e, pytest.mark.timeout(180)]

MS_PER_CHAR = 40
FALSE_BARGE_IN = re.compile(r"false barge-in \((\d+) ms of speech, (\d+) word")
STORY = "Once upon a time there was a robot who loved to talk about everything it saw." * 3


@dataclass
class Graph:
    probe: Any
    openai: Any
    mic: Microphone
    agent_out: Output
    check: Callable[[], None]

    def played(self, stream: str) -> int:
        return max((s.played_ms for s in list(self.probe.playback) if s.stream_id == stream), default=0)

    def story_playing(self) -> str:
        """Asks for the story; its stream once a second of it has played."""
        self.probe.type_text("tell me a story")
        return until(
            lambda: next((s.stream_id for s in list(self.probe.playback) if s.played_ms >= 1000), None),
            "a second of the story played",
            self.check,
        )

    def resumed(self, stream: str) -> int:
        """Waits for the resume; the played position then."""
        until(
            lambda: any(i.action == Interruption.RESUME for i in self.probe.interruptions),
            "the resume",
            self.check,
        )
        assert [(i.stream_id, i.action) for i in self.probe.interruptions] == [
            (stream, Interruption.PAUSE),
            (stream, Interruption.RESUME),
        ]
        return self.played(stream)


@contextmanager
def barge_in_graph(ros_namespace: str, tmp_path: Path, **settings: Any) -> Iterator[Graph]:
    """Microphone → VAD → bridge → agent (echo_mode external, `settings`) → player, the story
    and then "Yes?" scripted."""
    script = Script(turns=(Turn(Say(STORY)), Turn(Say("Yes?"))), ms_per_char=MS_PER_CHAR)
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(ros_namespace))
        player = stack.enter_context(player_process(ros_namespace, tmp_path / "played.wav"))
        vad, _ = stack.enter_context(vad_process(ros_namespace))
        probe.wait_nodes(alive(player, vad), player=True)
        port, _ = stack.enter_context(bridge_process(ros_namespace))
        config, agent_settings = agent_config(tmp_path, openai.url, echo_mode="external", **settings)
        agent, agent_out = stack.enter_context(agent_process(config, port))
        check = alive(agent, player, vad)
        probe.wait_agents_ready(ros_namespace, [setup_requests(agent_settings)])
        mic_out = probe.probe.node.create_publisher(AudioChunk, "audio", AUDIO_IN)
        until(lambda: mic_out.get_subscription_count() > 0, "the VAD listening on audio", check)
        mic = stack.enter_context(Microphone(mic_out))
        yield Graph(probe, openai, mic, agent_out, check)


def test_a_cough_resumes_the_reply_and_a_later_question_truncates_at_all_that_was_heard(
    ros_namespace: str, tmp_path: Path
) -> None:
    # Judged on the speech's length alone here, so that counting the VAD's pre-roll would
    # confirm the cough (the next test covers the words).
    with barge_in_graph(ros_namespace, tmp_path, min_barge_in_words=0) as graph:
        probe, openai, check = graph.probe, graph.openai, graph.check
        stream = graph.story_playing()
        # A cough: Silero hears it (an onset, with 480 ms of pre-roll before it) but it is short.
        graph.mic.say(spoken("ha"))
        resumed_at = graph.resumed(stream)
        until(
            lambda: graph.played(stream) >= resumed_at + 1500, "the story went on, on the same stream", check
        )

        # A real question over the rest of it: paused, then cut where it paused.
        graph.mic.say(corpus_utterance(0))  # "Hello robot, what do you see?"
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
        assert not graph.mic.busy()
    lines = graph.agent_out.finish()
    assert any("false barge-in" in line for line in lines)
    assert any("barge-in confirmed" in line for line in lines)


def test_a_backchannel_resumes_the_reply_and_real_words_cut_it(ros_namespace: str, tmp_path: Path) -> None:
    """Judged on the words the agent's own recogniser hears in the held audio: "okay okay" is
    ~700 ms of speech, long enough to interrupt by length alone, but says "go on"."""
    with barge_in_graph(ros_namespace, tmp_path) as graph:
        probe, check = graph.probe, graph.check
        stream = graph.story_playing()
        graph.mic.say(spoken("okay okay"))
        resumed_at = graph.resumed(stream)
        until(
            lambda: graph.played(stream) >= resumed_at + 1000, "the story went on, on the same stream", check
        )
        assert not graph.openai.events("conversation.item.truncate")

        graph.mic.say(corpus_utterance(0))  # "Hello robot, what do you see?"
        until(
            lambda: [s for s in list(probe.playback) if s.stream_id == stream and s.interrupted],
            "the story cut",
            check,
        )
        until(lambda: "Yes?" in probe.texts(probe.replies), "the question answered", check)
        actions = [(i.stream_id, i.action) for i in probe.interruptions]
        assert actions[2:] == [(stream, Interruption.PAUSE), (stream, Interruption.CUT)]
    lines = graph.agent_out.finish()
    # Refused on its words, not its length: long enough, no word that is not a backchannel.
    false = [m for line in lines if (m := FALSE_BARGE_IN.search(line))]
    assert [int(words) for _, words in (m.groups() for m in false)] == [0]
    assert int(false[0].group(1)) >= AgentConfig.min_barge_in_ms
    assert any("barge-in confirmed" in line for line in lines)
