"""echo_suppressor in a real graph: gate mode drops `audio` while assistant_speaking is True."""

from __future__ import annotations

import array

import pytest
from by_your_command_msgs.msg import AudioChunk
from byc_testing import python_module, running_process, wait_for
from ros_probe import probe_node
from std_msgs.msg import Bool

from by_your_command.nodes._qos import LATCHED, STREAM

CLOSED_AFTER = 40  # this many chunks in a row gone on loopback means the gate is shut, not packet loss


def _chunk(marker: int) -> AudioChunk:
    msg = AudioChunk(sample_rate=16000, channels=1)
    msg.data = array.array("h", [marker % 30000] * 512)
    return msg


@pytest.mark.ros
def test_gate_mode_drops_audio_while_the_assistant_speaks(ros_namespace: str) -> None:
    command = python_module(
        "by_your_command.nodes.echo_suppressor",
        "--ros-args", "-r", f"__ns:={ros_namespace}", "-p", "mode:=gate", "-p", "gate_tail_ms:=0",
    )  # fmt: skip
    with probe_node(ros_namespace) as probe, running_process(command) as node:
        audio = probe.node.create_publisher(AudioChunk, "audio", STREAM)
        speaking = probe.node.create_publisher(Bool, "assistant_speaking", LATCHED)
        out = probe.listen(AudioChunk, "audio_filtered", STREAM)
        sent = 0

        def alive() -> None:
            assert node.poll() is None, node.stdout.read() if node.stdout else "node died"

        def send() -> None:
            nonlocal sent
            sent += 1
            audio.publish(_chunk(sent))
            probe.spin(0.005)

        def received_after(marker: int) -> bool:
            alive()
            send()
            return any(int(msg.data[0]) > marker for msg in out)

        wait_for(
            lambda: audio.get_subscription_count() > 0 and speaking.get_subscription_count() > 0,
            timeout=20,
            what="echo_suppressor to discover us",
        )
        wait_for(lambda: received_after(0), timeout=10, what="audio to pass while the assistant is silent")
        assert out[-1].sample_rate == 16000 and len(out[-1].data) == 512

        speaking.publish(Bool(data=True))
        last_seen = {"count": len(out), "sent": sent}

        def gate_closed() -> bool:
            alive()
            send()
            if len(out) != last_seen["count"]:
                last_seen.update(count=len(out), sent=sent)
            return sent - last_seen["sent"] >= CLOSED_AFTER

        wait_for(gate_closed, timeout=10, what=f"{CLOSED_AFTER} chunks in a row dropped while speaking")
        closed_at = sent

        speaking.publish(Bool(data=False))
        wait_for(
            lambda: received_after(closed_at),
            timeout=10,
            what="audio to pass again after the assistant stopped",
        )
