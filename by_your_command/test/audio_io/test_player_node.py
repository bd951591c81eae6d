"""simple_audio_player in a real graph with a WAV sink: status, assistant_speaking, interruption
by name, bad input, and what it leaves behind when stopped."""

from __future__ import annotations

import signal
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from by_your_command_msgs.msg import AudioChunk, Interruption, PlaybackStatus
from byc_testing import python_module, running_process, wait_for
from ros_probe import Probe, probe_node
from std_msgs.msg import Bool

from by_your_command.audio.pcm import read_wav
from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

VOICE_RATE = 24000
SINK_RATE = 16000


@dataclass
class Graph:
    probe: Probe
    node: subprocess.Popen[str]
    voice: Any
    interrupt: Any
    speaking: list[Bool]
    status: list[PlaybackStatus]
    played: list[AudioChunk]

    def spin_alive(self) -> None:
        assert self.node.poll() is None, self.node.stdout.read() if self.node.stdout else "player died"
        self.probe.spin(0.01)

    def until(self, condition: Any, what: str, timeout: float = 10) -> None:
        def check() -> bool:
            self.spin_alive()
            return bool(condition())

        wait_for(check, timeout=timeout, what=what)

    def send(self, stream_id: str, pcm: np.ndarray, rate: int = VOICE_RATE, end: bool = False) -> None:
        msg = make_audio_chunk(pcm, rate, 1, stream_id=stream_id)
        msg.end_of_stream = end
        self.voice.publish(msg)
        self.probe.spin(0.0)

    def send_reply(self, stream_id: str, seconds: float, end: bool = True) -> None:
        t = np.arange(int(seconds * VOICE_RATE)) / VOICE_RATE
        pcm = np.rint(6000 * np.sin(2 * np.pi * 330 * t)).astype(np.int16)
        for k in range(0, len(pcm), 2400):  # 100 ms chunks
            self.send(stream_id, pcm[k : k + 2400])
        if end:
            self.send(stream_id, np.zeros(0, dtype=np.int16), end=True)

    def statuses(self, stream_id: str) -> list[PlaybackStatus]:
        return [s for s in self.status if s.stream_id == stream_id]


@contextmanager
def player_graph(ros_namespace: str, wav: Path) -> Iterator[Graph]:
    command = python_module(
        "by_your_command.nodes.simple_audio_player",
        "--ros-args", "-r", f"__ns:={ros_namespace}",
        "-p", "sink:=wav", "-p", f"wav_path:={wav}", "-p", f"sample_rate:={SINK_RATE}", "-p", "block_ms:=20",
    )  # fmt: skip
    with probe_node(ros_namespace) as probe, running_process(command) as node:
        graph = Graph(
            probe,
            node,
            probe.node.create_publisher(AudioChunk, "response_voice", RELIABLE),
            probe.node.create_publisher(Interruption, "interruption_signal", RELIABLE),
            probe.listen(Bool, "assistant_speaking", LATCHED),
            probe.listen(PlaybackStatus, "playback_status", RELIABLE),
            probe.listen(AudioChunk, "audio_played", STREAM),
        )
        graph.until(
            lambda: (
                graph.voice.get_subscription_count() > 0
                and graph.interrupt.get_subscription_count() > 0
                and graph.speaking
            ),
            "the player to come up and latch assistant_speaking",
            timeout=20,
        )
        assert graph.speaking[-1].data is False
        yield graph


def interruption(stream_id: str = "", reason: str = "barge_in") -> Interruption:
    return Interruption(stream_id=stream_id, reason=reason)


@pytest.mark.ros
def test_an_interruption_naming_a_reply_cuts_it_and_the_next_reply_plays_whole(
    ros_namespace: str, tmp_path: Path
) -> None:
    wav = tmp_path / "played.wav"
    with player_graph(ros_namespace, wav) as graph:
        graph.send_reply("resp-1", 4.0, end=False)
        graph.until(lambda: any(s.played_ms >= 300 for s in graph.statuses("resp-1")), "300 ms of resp-1")
        assert graph.speaking[-1].data is True
        assert graph.played[0].sample_rate == SINK_RATE and graph.played[0].stream_id == "resp-1"
        assert all(len(chunk.data) <= SINK_RATE // 50 for chunk in graph.played)

        graph.send_reply("resp-2", 0.3)  # its first chunk is in before the interruption for resp-1
        graph.interrupt.publish(interruption("resp-1"))
        graph.until(lambda: any(s.finished for s in graph.statuses("resp-2")), "resp-2 played to its end")
        graph.until(lambda: graph.speaking[-1].data is False, "assistant_speaking False")

        cut = [s for s in graph.statuses("resp-1") if s.interrupted]
        assert cut and not any(s.finished for s in cut) and cut[0].queued_ms == 0
        assert {s.played_ms for s in cut} == {cut[0].played_ms}  # frozen: it never grows afterwards
        frozen_ms = cut[0].played_ms
        assert 300 <= frozen_ms < 4000
        assert max(s.played_ms for s in graph.statuses("resp-1")) == frozen_ms
        done = [s for s in graph.statuses("resp-2") if s.finished][-1]
        assert (done.played_ms, done.interrupted, done.speaking) == (300, False, False)
        first_of_2 = next(i for i, c in enumerate(graph.played) if c.stream_id == "resp-2")
        assert {c.stream_id for c in graph.played[first_of_2:]} == {"resp-2"}  # no resp-1 after

    samples, rate, _ = read_wav(wav)  # what was heard: resp-1 up to the cut, then all of resp-2
    heard_1 = frozen_ms * rate // 1000
    assert len(samples) - int(0.3 * rate) in range(heard_1, heard_1 + rate // 1000)


@pytest.mark.ros
def test_a_blanket_interruption_silences_at_once_and_freezes_played_ms(
    ros_namespace: str, tmp_path: Path
) -> None:
    with player_graph(ros_namespace, tmp_path / "played.wav") as graph:
        graph.send_reply("resp-1", 3.0)
        graph.until(lambda: any(s.played_ms >= 200 for s in graph.statuses("resp-1")), "200 ms of resp-1")
        graph.interrupt.publish(interruption())  # no stream_id, no stamp: everything held now
        graph.until(lambda: any(s.interrupted for s in graph.status), "an interrupted status")
        first = next(s for s in graph.status if s.interrupted)
        assert first.stream_id == "resp-1" and first.speaking is False and first.queued_ms == 0
        graph.until(lambda: graph.speaking[-1].data is False, "assistant_speaking False")
        # Late chunks of the cut reply are dropped: nothing more is played or reported.
        graph.send_reply("resp-1", 0.2)
        graph.send_reply("resp-2", 0.1)
        graph.until(lambda: any(s.finished for s in graph.statuses("resp-2")), "resp-2 played")
        assert {s.played_ms for s in graph.statuses("resp-1") if s.interrupted} == {first.played_ms}
        assert not any(s.speaking for s in graph.statuses("resp-1") if s.interrupted)


@pytest.mark.ros
def test_a_paused_reply_holds_its_place_and_resumes_where_it_stopped(
    ros_namespace: str, tmp_path: Path
) -> None:
    """Interruption.action PAUSE / RESUME (an agent judging speech over the reply): played_ms runs
    on over the pause, the reply behind it waits, and a malformed pause is refused."""
    wav = tmp_path / "played.wav"
    with player_graph(ros_namespace, wav) as graph:
        graph.send_reply("resp-1", 1.0)
        graph.send_reply("resp-2", 0.2)
        graph.until(lambda: any(s.played_ms >= 300 for s in graph.statuses("resp-1")), "300 ms of resp-1")
        pause = Interruption(stream_id="resp-1", reason="barge_in", action=Interruption.PAUSE)
        graph.interrupt.publish(pause)
        graph.until(lambda: any(s.paused for s in graph.statuses("resp-1")), "resp-1 paused")
        graph.until(lambda: graph.speaking[-1].data is False, "assistant_speaking False while paused")
        at_pause = next(s for s in graph.statuses("resp-1") if s.paused)
        assert not at_pause.speaking and at_pause.queued_ms > 0
        graph.interrupt.publish(Interruption(reason="bad", action=Interruption.PAUSE))  # no stream named
        graph.interrupt.publish(Interruption(stream_id="resp-1", reason="bad", action=9))
        graph.interrupt.publish(
            Interruption(stream_id="resp-1", reason="not noise", action=Interruption.RESUME)
        )
        graph.until(lambda: any(s.finished for s in graph.statuses("resp-2")), "resp-2 played after resp-1")
        assert not any(s.interrupted for s in graph.statuses("resp-1"))
        # resp-1 ended while resp-2 played on: its end is reported all the same
        graph.until(lambda: any(s.finished for s in graph.statuses("resp-1")), "resp-1 reported finished")
        assert [s.played_ms for s in graph.statuses("resp-1") if s.finished] == [1000]
        played = [s.played_ms for s in graph.statuses("resp-1")]
        assert played == sorted(played)  # continuous: never back to 0 after the resume
    samples, rate, _ = read_wav(wav)
    assert len(samples) == int(1.2 * rate)  # all of both replies, nothing twice


BAD_CHUNKS = [
    (4_294_967_291, 1, 480),
    (1_000_003, 1, 480),
    (0, 1, 480),
    (VOICE_RATE, 0, 480),
    (VOICE_RATE, 200, 400),
    (VOICE_RATE, 2, 481),
]


@pytest.mark.ros
def test_bad_chunks_are_refused_loudly_and_a_stopped_player_leaves_speaking_false(
    ros_namespace: str, tmp_path: Path
) -> None:
    with player_graph(ros_namespace, tmp_path / "played.wav") as graph:
        for rate, channels, samples in BAD_CHUNKS:
            msg = make_audio_chunk(np.zeros(samples, dtype=np.int16), 24000, 1, stream_id="bad")
            msg.sample_rate, msg.channels = rate, channels
            graph.voice.publish(msg)
        graph.send_reply("good", 0.2)
        graph.until(lambda: any(s.finished for s in graph.statuses("good")), "the good reply played")
        assert not graph.statuses("bad")

        graph.send_reply("long", 5.0, end=False)
        graph.until(lambda: any(s.played_ms >= 100 for s in graph.statuses("long")), "the long reply")
        assert graph.speaking[-1].data is True
        graph.node.send_signal(signal.SIGTERM)
        assert graph.node.wait(timeout=10) == 0
        output = graph.node.stdout.read() if graph.node.stdout else ""

        def final_state_arrived() -> bool:
            graph.probe.spin(0.01)
            return graph.speaking[-1].data is False and any(s.interrupted for s in graph.statuses("long"))

        wait_for(final_state_arrived, timeout=5, what="assistant_speaking False from the stopped player")
        last = graph.statuses("long")[-1]
        assert last.interrupted and not last.speaking and not last.finished
    assert "rejected" in output and "sample_rate" in output and "partial_frame" in output
    assert "rejected={'sample_rate': 3, 'channels': 2, 'partial_frame': 1}" in output
