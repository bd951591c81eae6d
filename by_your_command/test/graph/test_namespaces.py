"""Two complete graphs under two namespaces on one machine do not cross-talk: each namespace's
subscriber gets utterances cut from its own WAV file only."""

from __future__ import annotations

import signal
import uuid
from collections.abc import Callable

import numpy as np
import pytest
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance
from byc_testing import wait_for
from graph.up_runner import UpProcess, byc_up, wait_for_exit
from ros_probe import Probe, probe_node
from std_msgs.msg import String
from vad.corpus import Session, sessions

from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM


def voice_graph(namespace: str, session: Session) -> list[str]:
    settings = [
        f"audio_source=file:{session.path}",
        "enable_voice_recorder=false",
        "echo_mode=external",  # pass-through: utterances hold the file's samples exactly
        "file_audio_publisher.rate_factor=3.0",
        "file_audio_publisher.chunk_samples=1600",
        # the VAD + this test's probe: the file starts once the probe saw the VAD ready
        "file_audio_publisher.min_subscribers=2",
    ]
    return ["byc", "--namespace", namespace, *(word for s in settings for word in ("--set", s))]


class Robot:
    """One namespace as its own subscriber sees it."""

    def __init__(self, probe: Probe, namespace: str, session: Session, up: UpProcess) -> None:
        self.probe, self.namespace, self.session, self.up = probe, namespace, session, up
        node = probe.node
        self.chunks: list[AudioDataUtterance] = []
        self.states: list[String] = []
        node.create_subscription(
            AudioDataUtterance, f"{namespace}/prompt_voice", self.chunks.append, RELIABLE
        )
        node.create_subscription(String, f"{namespace}/attention_state", self.states.append, LATCHED)

    def vad_ready(self) -> bool:
        return bool(self.states) and self.probe.node.count_subscribers(f"{self.namespace}/audio") >= 1

    def start_file(self) -> None:
        self.probe.node.create_subscription(AudioChunk, f"{self.namespace}/audio", lambda _: None, STREAM)

    def heard(self, utterances: int) -> bool:
        return bool(sum(chunk.is_utterance_end for chunk in self.chunks) >= utterances)


def spin_until(probe: Probe, robots: list[Robot], condition: Callable[[], object], what: str) -> None:
    def step() -> object:
        for robot in robots:
            robot.up.check_running()
        probe.spin(0.02)
        return condition()

    wait_for(step, timeout=40, what=what)


def found_in(samples: np.ndarray, piece: np.ndarray) -> bool:
    """`piece` occurs in `samples` at a sample boundary."""
    haystack, needle = samples.astype("<i2").tobytes(), piece.astype("<i2").tobytes()
    start = haystack.find(needle)
    while start != -1 and start % 2:
        start = haystack.find(needle, start + 1)
    return bool(start != -1)


@pytest.mark.ros
def test_two_namespaces_do_not_cross_talk() -> None:
    corpus = {s.name: s for s in sessions()}
    a_session, b_session = corpus["clean_en_us"], corpus["white_noise_en_gb"]
    run = uuid.uuid4().hex[:8]
    a_ns, b_ns = f"/robot_a_{run}", f"/robot_b_{run}"
    with (
        probe_node(a_ns) as probe,
        byc_up(*voice_graph(a_ns, a_session)) as a_up,
        byc_up(*voice_graph(b_ns, b_session)) as b_up,
    ):
        robots = [Robot(probe, a_ns, a_session, a_up), Robot(probe, b_ns, b_session, b_up)]
        spin_until(probe, robots, lambda: all(r.vad_ready() for r in robots), "both VADs to be ready")
        for robot in robots:
            robot.start_file()
        spin_until(probe, robots, lambda: all(r.heard(2) for r in robots), "two utterances in each namespace")
        for robot in robots:  # both at once: stopping is the slow part
            robot.up.process.send_signal(signal.SIGTERM)
        statuses = [wait_for_exit(robot.up) for robot in robots]
        assert statuses == [0, 0], a_up.output + "\n" + b_up.output

    audio = {robot.namespace: robot.session.audio() for robot in robots}
    for robot, other in (robots, robots[::-1]):
        pieces = [np.asarray(c.int16_data, dtype=np.int16) for c in robot.chunks]
        speech = [piece for piece in pieces if np.any(piece)]
        assert all(found_in(audio[robot.namespace], piece) for piece in speech), (
            f"{robot.namespace}: foreign audio"
        )
        assert not any(found_in(audio[other.namespace], piece) for piece in speech), (
            f"{other.namespace} leaked"
        )
