"""The echo_suppressor node in aec mode as a test's peer (a process on a real graph): the mic goes
to `audio`, what played to `audio_played`, and what comes out of `audio_filtered` is collected."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from audio_io.synthetic_room import energy_db
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk
from byc_testing import python_module, running_process, wait_for
from rclpy.publisher import Publisher
from ros_probe import Probe, probe_node
from std_msgs.msg import Bool

from by_your_command.audio.pcm import Int16Array
from by_your_command.nodes._audio_msgs import make_audio_chunk, pcm_of
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

    def send(self, pcm: Int16Array, start_ns: int, reference: Int16Array | None) -> None:
        """One mic block, then what played meanwhile (the worst order), in lockstep: the output
        must reach two blocks back before the next (a lost best-effort block is resynchronised
        on the next one)."""
        self.audio.publish(make_audio_chunk(pcm, RATE, 1, to_stamp(start_ns)))
        if reference is not None:
            self.played.publish(make_audio_chunk(reference, RATE, 1, to_stamp(start_ns), "resp"))
        wait_for(
            lambda: self.covered_until(start_ns - samples_ns(2 * BLOCK)),
            timeout=5,
            what=f"filtered audio up to {(start_ns - T0) / NS_PER_S:.3f} s",
        )

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


def reduction_db(mic: Int16Array, out: list[AudioChunk], start_ns: int, lo: int, hi: int) -> float:
    """How far the output is below the mic over samples [lo, hi) of a reply that started at
    `start_ns`: the median over its 32 ms blocks where the echo sounds (output laid out by its
    stamps). A median: a reference block lost on the best-effort topic, or later than the mic's
    wait, leaves its block uncancelled, and over seconds of energy that one block alone reads
    21 dB (seen on a loaded machine)."""
    heard = np.zeros(hi - lo, dtype=np.int16)
    covered = np.zeros(hi - lo, dtype=bool)
    for msg in out:
        at = round((stamp_ns(msg.header.stamp) - start_ns) * RATE / NS_PER_S) - lo
        pcm = pcm_of(msg)
        first, last = max(at, 0), min(at + len(pcm), hi - lo)
        if last > first:
            heard[first:last] = pcm[first - at : last - at]
            covered[first:last] = True
    assert covered.mean() > 0.8, "output missing for the reply"
    reductions = []
    loudest = max(energy_db(mic[k : k + BLOCK]) for k in range(lo, hi, BLOCK))
    for k in range(0, hi - lo - BLOCK + 1, BLOCK):
        sounding = energy_db(mic[lo + k : lo + k + BLOCK]) > loudest - 30.0
        if sounding and covered[k : k + BLOCK].all():
            reductions.append(energy_db(mic[lo + k : lo + k + BLOCK]) - energy_db(heard[k : k + BLOCK]))
    assert len(reductions) > 10, "too little echo to judge"
    return float(np.median(reductions))
