"""The microphone side of the agent graph tests: a live microphone publishing `audio` in real
time (a faint room; sounds mixed in on one timeline), the VAD process that listens to it, and
spoken test phrases (espeak-ng through the package's speaker)."""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from agent_graph import VAD_RATE, Output
from builtin_interfaces.msg import Time
from byc_testing import python_module, running_process

from by_your_command.local_speech.speaker import Speaker, SpeakerConfig
from by_your_command.nodes._audio_msgs import make_audio_chunk

BLOCK = 512  # the microphone's block: 32 ms
NS_PER_S = 1_000_000_000


class Microphone:
    """A live microphone on `audio`: a faint room, in real time, stamped on one timeline; `say`
    mixes a sound in at the next block."""

    def __init__(self, publisher: object) -> None:
        self._publisher = publisher
        self._pending: list[np.ndarray] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.said_at: list[float] = []

    def say(self, pcm: np.ndarray) -> None:
        with self._lock:
            self._pending.append(pcm.astype(np.int16))

    def busy(self) -> bool:
        with self._lock:
            return bool(self._pending)

    def _run(self) -> None:
        rng = np.random.default_rng(5)
        start_wall, start_mono = time.time_ns(), time.monotonic()
        sent = 0
        queued = np.zeros(0, dtype=np.int16)
        while not self._stop.is_set():
            with self._lock:
                if self._pending and not len(queued):
                    queued = self._pending.pop(0)
                    self.said_at.append(time.monotonic())
            block = rng.normal(0, 30, BLOCK).astype(np.int16)
            if len(queued):
                part, queued = queued[:BLOCK], queued[BLOCK:]
                block[: len(part)] = np.clip(block[: len(part)].astype(np.int32) + part, -32768, 32767)
            stamp = start_wall + sent * NS_PER_S // VAD_RATE
            self._publisher.publish(  # type: ignore[attr-defined]
                make_audio_chunk(block, VAD_RATE, 1, Time(sec=stamp // NS_PER_S, nanosec=stamp % NS_PER_S))
            )
            sent += BLOCK
            self._stop.wait(max(0.0, start_mono + sent / VAD_RATE - time.monotonic()))

    def __enter__(self) -> Microphone:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


@contextmanager
def vad_process(
    namespace: str, stop_spotter: bool = False, echo_gate: bool = False
) -> Iterator[tuple[subprocess.Popen[str], Output]]:
    """The VAD with the shipped defaults (pre-roll 480 ms), and its output lines, read as they come
    (an unread pipe blocks the node once full) and printed at the end (pytest shows them only when
    the test failed). Its stop spotter is off unless asked: it leans to stopping, and now and then
    takes a one-word cough ("ha", heard "car") for a stop, which is its own figure
    (bench_safety_stop.py: false stops), not the barge-in judge's."""
    command = python_module(
        "by_your_command.nodes.silero_vad_node",
        "--ros-args", "-r", f"__ns:={namespace}", "-p", "input_topic:=audio",
        "-p", f"echo_gate:={str(echo_gate).lower()}", "-p", f"stop_spotter:={str(stop_spotter).lower()}",
    )  # fmt: skip
    with running_process(command) as process:
        output = Output(process)
        try:
            yield process, output
        finally:
            print("--- silero_vad_node:", *list(output.lines), sep="\n")


def spoken(text: str) -> np.ndarray:
    pcm, rate = Speaker(SpeakerConfig(voice="en-us", sample_rate=VAD_RATE)).say(text)
    assert rate == VAD_RATE
    return np.frombuffer(pcm, dtype="<i2")
