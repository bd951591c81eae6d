"""The VAD's own half-duplex gate (`echo_gate`, the profiles' gate echo mode): the robot starting
to speak ends the open utterance at once, and what the mic hears while it speaks is never an
utterance; once it stops (and the tail passed), speech is heard again. The test is a live mic:
each block is stamped with its capture time and sent once that time has come."""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance
from byc_testing import running_process
from ros_probe import probe_node
from std_msgs.msg import Bool
from vad.corpus import sessions
from vad.test_graph import alive, node, spin_until

from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

BLOCK = 512
NS_PER_SAMPLE = 1_000_000_000 // 16000


@pytest.mark.ros
def test_the_vad_gates_itself_while_the_assistant_speaks(ros_namespace: str) -> None:
    speech = next(s for s in sessions() if s.name == "clean_en_us").audio()[8000 : 16000 * 3]
    silence = np.zeros(16000, np.int16)
    utterance = np.concatenate([silence, speech, silence])
    vad_params = (
        "input_topic:=audio",
        "echo_gate:=true",
        "gate_tail_ms:=0",
        # Only the gate can end an utterance within the test's time: not the audio timeout.
        "audio_timeout_ms:=600000",
    )
    with (
        probe_node(ros_namespace) as probe,
        running_process(node("silero_vad_node", ros_namespace, *vad_params)) as vad,
    ):
        check = alive(vad)
        activity = probe.listen(Bool, "voice_activity", RELIABLE)
        chunks: list[AudioDataUtterance] = []
        voice = probe.node.create_subscription(AudioDataUtterance, "prompt_voice", chunks.append, RELIABLE)
        audio = probe.node.create_publisher(AudioChunk, "audio", STREAM)
        speaking = probe.node.create_publisher(Bool, "assistant_speaking", LATCHED)
        spin_until(
            probe,
            check,
            lambda: (
                audio.get_subscription_count()
                and speaking.get_subscription_count()
                and voice.get_publisher_count()
            ),
            timeout=30,
            what="the VAD node",
        )

        def now_ns() -> int:
            return int(probe.node.get_clock().now().nanoseconds)

        def play_until(samples: np.ndarray, done: object = None) -> int:
            """Plays like a microphone; returns the stamp of the first block."""
            start = now_ns()
            for offset in range(0, len(samples), BLOCK):
                captured = start + (offset + BLOCK) * NS_PER_SAMPLE
                spin_until(
                    probe, check, lambda at=captured: now_ns() >= at, timeout=30, what="the block's time"
                )
                stamp = start + offset * NS_PER_SAMPLE
                stamped = Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
                audio.publish(make_audio_chunk(samples[offset : offset + BLOCK], 16000, 1, stamped))
                if callable(done) and done():
                    break
            return start

        def heard_since(stamp: int) -> list[int]:
            """Utterances (their first sample's stamp) that ended, from `stamp` on."""
            return [c.utterance_id for c in chunks if c.is_utterance_end and c.utterance_id >= stamp]

        # 1. The user is mid-utterance when the robot starts to speak: the utterance ends now.
        cut = play_until(utterance, lambda: [a.data for a in activity] == [True])
        assert [a.data for a in activity] == [True], "no speech heard before the robot spoke"
        speaking.publish(Bool(data=True))
        spin_until(
            probe,
            check,
            lambda: heard_since(cut) and [a.data for a in activity] == [True, False],
            timeout=30,
            what="the open utterance ended by the gate",
        )

        # 2. Speech while the robot speaks is not heard; after it stops, the same speech is.
        gated = play_until(utterance)
        speaking.publish(Bool(data=False))
        after = play_until(utterance)
        spin_until(probe, check, lambda: heard_since(after), timeout=30, what="speech heard again")
        assert [c.utterance_id for c in chunks if gated <= c.utterance_id < after] == []
        assert len(heard_since(cut)) == 1 + len(heard_since(after))
