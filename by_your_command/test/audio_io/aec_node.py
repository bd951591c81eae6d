"""The echo_suppressor node in aec mode as a test's peer (a process on a real graph): the mic goes
to `audio`, what played to `audio_played`, and what comes out of `audio_filtered` is collected."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk
from byc_testing import python_module, running_process, wait_for
from rclpy.publisher import Publisher
from ros_probe import Probe, probe_node
from std_msgs.msg import Bool

from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import LATCHED, STREAM

RATE = 16000
BLOCK = 512
NS_PER_S = 1_000_000_000
T0 = 1_700_000_000 * NS_PER_S


def stamp_ns(stamp: Time) -> int:
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def to_stamp(ns: int) -> Time:
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


def samples_ns(count: int) -> int:
    return count * NS_PER_S // RATE


@dataclass
class AecNode:
    probe: Probe
    process: subprocess.Popen[str]
    audio: Publisher  # the mic
    played: Publisher  # the reference
    speaking: Publisher
    out: list[AudioChunk]  # audio_filtered, as it came

    def covered_until(self, time_ns: int) -> bool:
        """The output reaches `time_ns` (the node still running)."""
        process = self.process
        assert process.poll() is None, process.stdout.read() if process.stdout else "node died"
        self.probe.spin(0.002)
        return any(stamp_ns(m.header.stamp) + samples_ns(len(m.data)) >= time_ns for m in self.out[-4:])

    def wait_heard(self) -> None:
        """Until the node demonstrably hears us (the first best-effort messages after discovery may
        be lost): silence stamped well before the test audio. The output is cleared after."""
        warm_up = iter(range(10_000))

        def heard() -> bool:
            stamp = to_stamp(T0 - 10 * NS_PER_S + samples_ns(next(warm_up) * BLOCK))
            self.audio.publish(make_audio_chunk(np.zeros(BLOCK, dtype=np.int16), RATE, 1, stamp))
            self.probe.spin(0.01)
            return bool(self.out)

        wait_for(heard, timeout=10, what="the node to hear us")
        self.out.clear()


@contextmanager
def aec_node(namespace: str, *parameters: str) -> Iterator[AecNode]:
    """The node (`-p` parameters after mode:=aec) and our publishers, once all have matched."""
    command = python_module(
        "by_your_command.nodes.echo_suppressor",
        "--ros-args", "-r", f"__ns:={namespace}", "-p", "mode:=aec", *parameters,
    )  # fmt: skip
    with probe_node(namespace) as probe, running_process(command) as process:
        node = AecNode(
            probe,
            process,
            probe.node.create_publisher(AudioChunk, "audio", STREAM),
            probe.node.create_publisher(AudioChunk, "audio_played", STREAM),
            probe.node.create_publisher(Bool, "assistant_speaking", LATCHED),
            probe.listen(AudioChunk, "audio_filtered", STREAM),
        )
        wait_for(
            lambda: (
                node.audio.get_subscription_count() > 0
                and node.played.get_subscription_count() > 0
                and node.speaking.get_subscription_count() > 0
                and probe.node.count_publishers("audio_filtered") > 0
            ),
            timeout=20,
            what="echo_suppressor (aec) and us to discover each other",
        )
        yield node
