"""The VAD's own half-duplex gate (`echo_gate`, the profiles' gate echo mode): what the mic hears
while the robot speaks never starts an utterance, and once it stops (and the tail passed), speech
is heard again; but an utterance the user began before the robot started is heard to its end,
for at most `gate_hold_ms`. The test is a live mic: each block is stamped with its capture time
and sent once that time has come."""

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
HOLD_MS = 4500
# Silence that ends an utterance: longer than the pauses inside the corpus's sentences, so the
# speech said three times over is one utterance, longer than the hold.
MIN_SILENCE_MS = 1000


@pytest.mark.ros
def test_the_vad_gates_itself_while_the_assistant_speaks(ros_namespace: str) -> None:
    speech = next(s for s in sessions() if s.name == "clean_en_us").audio()[8000 : 16000 * 3]
    silence = np.zeros(16000, np.int16)
    utterance = np.concatenate([silence, speech, silence, silence])
    vad_params = (
        "input_topic:=audio",
        "echo_gate:=true",
        "gate_tail_ms:=0",
        f"gate_hold_ms:={HOLD_MS}",
        f"min_silence_duration_ms:={MIN_SILENCE_MS}",
        # Only the gate or silence can end an utterance within the test's time: not the audio timeout.
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

        def play(samples: np.ndarray, at_onset: object = None) -> int:
            """Plays like a microphone, calling `at_onset` once speech is heard; returns the stamp
            of the first block."""
            start = now_ns()
            for offset in range(0, len(samples), BLOCK):
                captured = start + (offset + BLOCK) * NS_PER_SAMPLE
                spin_until(
                    probe, check, lambda at=captured: now_ns() >= at, timeout=30, what="the block's time"
                )
                stamp = start + offset * NS_PER_SAMPLE
                stamped = Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
                audio.publish(make_audio_chunk(samples[offset : offset + BLOCK], 16000, 1, stamped))
                if callable(at_onset) and activity and activity[-1].data:
                    at_onset()
                    at_onset = None
            return start

        def heard_since(stamp: int) -> dict[int, int]:
            """Utterances that ended, from `stamp` on: their first sample's stamp -> their length
            in samples."""
            ended = {c.utterance_id for c in chunks if c.is_utterance_end and c.utterance_id >= stamp}
            lengths = dict.fromkeys(ended, 0)
            for c in chunks:
                if c.utterance_id in lengths:
                    lengths[c.utterance_id] += len(c.int16_data)
            return lengths

        def end_of(utterance_id: int, samples: int) -> int:
            return utterance_id + samples * NS_PER_SAMPLE

        spoke_at: list[int] = []

        def robot_speaks() -> None:
            spoke_at.append(now_ns())
            speaking.publish(Bool(data=True))

        # 1. The user is mid-utterance when the robot starts to speak: the utterance is heard to
        # its end, whole (a late reply cut the next command to its first 0.45 s).
        begun = play(utterance, robot_speaks)
        assert spoke_at, "no speech heard before the robot spoke"
        spin_until(probe, check, lambda: heard_since(begun), timeout=30, what="the held utterance's end")
        ((first, samples),) = heard_since(begun).items()
        speech_ends = begun + (len(silence) + len(speech)) * NS_PER_SAMPLE
        assert first < spoke_at[0] and end_of(first, samples) >= speech_ends

        # 2. Speech that begins while the robot speaks is not heard; after it stops, the same is.
        gated = play(utterance)
        speaking.publish(Bool(data=False))
        after = play(utterance)
        spin_until(probe, check, lambda: heard_since(after), timeout=30, what="speech heard again")
        assert [u for u in heard_since(gated) if u < after] == []

        # 3. The hold is bounded: an utterance the robot's voice would keep going (speech that
        # goes on, here the sentence three times over) ends at the end of the hold, while the
        # robot still speaks, and nothing after it is heard.
        spoke_at.clear()
        long_talk = np.concatenate([silence, speech, speech, speech, silence])
        held = play(long_talk, robot_speaks)
        spin_until(probe, check, lambda: heard_since(held), timeout=30, what="the hold's end")
        ((first, samples),) = heard_since(held).items()
        talk_ends = held + (len(silence) + 3 * len(speech)) * NS_PER_SAMPLE
        assert spoke_at and end_of(first, samples) < talk_ends
        speaking.publish(Bool(data=False))
        assert list(heard_since(held)) == [first]
