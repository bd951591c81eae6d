"""echo_suppressor in aec mode in a real graph: the reference arrives on `audio_played` and the
mic on `audio`, aligned by their stamps; the echo in `audio_filtered` is much weaker."""

from __future__ import annotations

import numpy as np
import pytest
from audio_io.synthetic_room import Room, energy_db, recorded_speech
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk
from byc_testing import python_module, running_process, wait_for
from ros_probe import probe_node

from by_your_command.nodes._audio_msgs import make_audio_chunk, pcm_of
from by_your_command.nodes._qos import STREAM

RATE = 16000
BLOCK = 512
NS_PER_S = 1_000_000_000
T0 = 1_700_000_000 * NS_PER_S


def _stamp(ns: int) -> Time:
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


@pytest.mark.ros
def test_aec_node_cancels_the_played_audio_from_the_mic(ros_namespace: str) -> None:
    far = recorded_speech(6, RATE)
    mic = Room(delay_ms=100).echo(far, RATE)
    command = python_module(
        "by_your_command.nodes.echo_suppressor",
        "--ros-args", "-r", f"__ns:={ros_namespace}", "-p", "mode:=aec",
    )  # fmt: skip
    with probe_node(ros_namespace) as probe, running_process(command) as node:
        audio = probe.node.create_publisher(AudioChunk, "audio", STREAM)
        played = probe.node.create_publisher(AudioChunk, "audio_played", STREAM)
        out = probe.listen(AudioChunk, "audio_filtered", STREAM)
        wait_for(
            lambda: (
                audio.get_subscription_count() > 0
                and played.get_subscription_count() > 0
                and probe.node.count_publishers("audio_filtered") > 0
            ),
            timeout=20,
            what="echo_suppressor (aec) and us to discover each other",
        )

        def grew(before: int) -> bool:  # lockstep keeps every queue shallow: no best-effort drops
            assert node.poll() is None, node.stdout.read() if node.stdout else "node died"
            probe.spin(0.002)
            return len(out) > before

        def publish_played(k: int) -> None:
            start = T0 + k * NS_PER_S // RATE
            played.publish(make_audio_chunk(far[k : k + BLOCK], RATE, 1, _stamp(start), "resp"))

        # Worst case ordering: each reference block arrives after the mic block it belongs to
        # (in a room the player announces a block before its echo is even captured).
        for k in range(0, len(mic) // BLOCK * BLOCK, BLOCK):
            start = T0 + k * NS_PER_S // RATE
            before = len(out)
            audio.publish(make_audio_chunk(mic[k : k + BLOCK], RATE, 1, _stamp(start)))
            publish_played(k)
            try:
                wait_for(lambda before=before: grew(before), timeout=0.5, what="filtered audio")
            except AssertionError:
                pass  # a best-effort sample was lost on the way: carry on, we measure what arrived
        out_samples = sum(len(m.data) for m in out)
        assert out_samples > 0.8 * len(mic)

    # Compare what arrived with the mic samples at the same stamps, after AEC3 has converged.
    mic_part, out_part = [], []
    for msg in out:
        first = round(((msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec) - T0) * RATE / NS_PER_S)
        pcm = pcm_of(msg)
        if first >= 3 * RATE and first + len(pcm) <= len(mic):
            mic_part.append(mic[first : first + len(pcm)])
            out_part.append(pcm)
    reduction = energy_db(np.concatenate(mic_part)) - energy_db(np.concatenate(out_part))
    print(f"AEC echo reduction through the node: {reduction:.1f} dB")
    assert reduction > 12.0
