"""echo_suppressor in aec mode through a real graph, restarted: the first run learns the room's
echo path and keeps it (`aec_echo_memory`) when the reply ends; the second run starts from it and
cancels its first reply from the first second, where the first run was still learning."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from audio_io.aec_node import BLOCK, RATE, T0, AecNode, aec_node, reduction_db, samples_ns
from audio_io.synthetic_room import ROBOT_REPLY, Room, at_level, espeak, recorded_speech
from byc_testing import wait_for
from std_msgs.msg import Bool

from by_your_command.audio.pcm import Int16Array

pytestmark = [pytest.mark.ros, pytest.mark.timeout(240)]

ROOM = Room(delay_ms=120, noise_dbfs=-90.0)  # 0.6 s of response: seconds to learn from new
FIRST_SECOND = (0, RATE)
# The canceller's own output: the residual suppressor would hide what the filter does.
NO_SUPPRESSOR = ("-p", "echo_guard:=false")


def play(node: AecNode, played: Int16Array, mic: Int16Array) -> None:
    """The robot says `played` (the mic hears `mic`) from T0, then stops."""
    node.speaking.publish(Bool(data=True))
    for k in range(0, len(mic) // BLOCK * BLOCK, BLOCK):
        node.send(mic[k : k + BLOCK], T0 + samples_ns(k), played[k : k + BLOCK])
    node.speaking.publish(Bool(data=False))


@pytest.mark.ros
def test_a_restarted_node_cancels_its_first_reply_from_the_start(ros_namespace: str, tmp_path: Path) -> None:
    memory = tmp_path / "echo_path.npz"
    parameters = ("-p", f"aec_echo_memory:={memory}", *NO_SUPPRESSOR)
    # Two seconds of a reply, and a quarter of a second after it to flush the first second out.
    reply = at_level(espeak(ROBOT_REPLY, "en-gb", RATE), -18.0)[: 2 * RATE]
    reply = np.concatenate([reply, np.zeros(RATE // 4, dtype=np.int16)])
    # The first run: the reply, then 16 s more of the robot's voice to learn the room from.
    first_run = np.concatenate([reply, recorded_speech(16.0, RATE)])
    first_mic = ROOM.echo(first_run, RATE)
    with aec_node(ros_namespace, *parameters) as node:
        node.wait_heard()
        play(node, first_run, first_mic)
        wait_for(memory.exists, timeout=10, what="the echo path kept at the end of the reply")
        new = reduction_db(first_mic, node.out, T0, *FIRST_SECOND)

    mic = ROOM.echo(reply, RATE)
    with aec_node(ros_namespace, *parameters) as node:
        node.wait_heard()
        play(node, reply, mic)
        restarted = reduction_db(mic, node.out, T0, *FIRST_SECOND)

    print(f"first second of the reply: new {new:.1f} dB, started from the kept path {restarted:.1f} dB")
    assert new < 10.0  # the cold start this is about
    assert restarted > new + 8.0
