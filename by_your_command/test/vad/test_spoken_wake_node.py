"""Spoken wake on the real node (a process): asleep, speech is segmented and decoded on the robot,
never published; a spoken wake phrase wakes it, anything else is not acted on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance
from byc_testing import running_process
from rcl_interfaces.msg import Log
from ros_probe import Probe, probe_node
from std_msgs.msg import Bool, String
from vad.test_graph import ROSOUT, alive, node, spin_until
from vad.test_spoken_wake import espeak

from by_your_command.audio.pcm import Int16Array
from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

RATE = 16000
BLOCK = 512
NS_PER_S = 1_000_000_000


class Speaker:
    """Publishes audio as stamped blocks on one continuous timeline (no gaps for the VAD)."""

    def __init__(self, probe: Probe) -> None:
        self.probe = probe
        self.publisher = probe.node.create_publisher(AudioChunk, "audio", STREAM)
        self.next_ns = probe.node.get_clock().now().nanoseconds

    def say(self, pcm: Int16Array) -> int:
        """Publishes `pcm` followed by a second of silence; returns the stamp of its first sample."""
        first = self.next_ns
        audio = np.concatenate([pcm, np.zeros(RATE, dtype=np.int16)])
        for offset in range(0, len(audio) - BLOCK + 1, BLOCK):
            stamp = Time(sec=self.next_ns // NS_PER_S, nanosec=self.next_ns % NS_PER_S)
            self.publisher.publish(make_audio_chunk(audio[offset : offset + BLOCK], RATE, 1, stamp))
            self.next_ns += BLOCK * NS_PER_S // RATE
            self.probe.spin(0.002)
        return first


@pytest.mark.ros
def test_spoken_wake_up_wakes_a_sleeping_node_and_nothing_asleep_is_published(
    ros_namespace: str, tmp_path: Path
) -> None:
    look_down = espeak("look down", "en-us", tmp_path)
    wake_up = espeak("wake up", "en-us", tmp_path)
    command = node("silero_vad_node", ros_namespace, "input_topic:=audio", "start_awake:=false")
    with probe_node(ros_namespace) as probe, running_process(command) as vad:
        check = alive(vad)
        states = probe.listen(String, "attention_state", LATCHED)
        chunks = probe.listen(AudioDataUtterance, "prompt_voice", RELIABLE)
        activity = probe.listen(Bool, "voice_activity", RELIABLE)
        logger = f"{ros_namespace.strip('/')}.silero_vad_node"
        lines: list[str] = []
        probe.node.create_subscription(
            Log, "/rosout", lambda m: lines.append(m.msg) if m.name == logger else None, ROSOUT
        )
        speaker = Speaker(probe)

        def wait(condition: object, what: str) -> None:
            spin_until(probe, check, condition, timeout=30, what=what)  # type: ignore[arg-type]

        wait(
            lambda: states and speaker.publisher.get_subscription_count(),
            "the VAD node to come up",
        )
        assert states[-1].data == "asleep"

        speaker.say(look_down)
        wait(lambda: any("not a wake phrase" in x for x in lines), "'look down' to be decoded")
        assert states[-1].data == "asleep"

        speaker.say(wake_up)
        wait(lambda: states[-1].data == "awake", "spoken 'wake up' to wake the node")
        # /rosout and attention_state are two topics: no order between them is promised.
        wait(lambda: "attention: awake" in lines, "the node's log line for the change")
        decisions = [
            x for x in lines if "wake phrase" in x or "phrase heard" in x or x.startswith("attention:")
        ]
        assert decisions == [
            "attention: asleep",
            "spoken wake: not a wake phrase (1 so far)",
            "'wake' phrase heard in speech: 'wake up'",
            "attention: awake",
        ]
        # Nothing heard while asleep left the node: no utterance, not even voice activity.
        assert chunks == [] and activity == []

        # Awake, the same sentence is published, and holds nothing from before the wake.
        started = speaker.say(look_down)
        wait(lambda: any(c.is_utterance_end for c in chunks), "the awake utterance")
        assert {c.utterance_id for c in chunks} == {chunks[0].utterance_id}
        assert chunks[0].utterance_id >= started
        # voice_activity is another topic: its end may arrive after the utterance's last chunk.
        wait(lambda: len(activity) >= 2, "the awake utterance's voice activity to end")
        assert [a.data for a in activity] == [True, False]
