"""The audio front end as separate processes on a real rclpy graph:
file_audio_publisher -> silero_vad_node -> voice_chunk_recorder (the profiles' wiring without aec)."""

from __future__ import annotations

import signal
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance
from byc_testing import python_module, running_process, wait_for
from rcl_interfaces.msg import Log
from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy
from ros_probe import Probe, probe_node
from std_msgs.msg import Bool, String
from vad.corpus import sessions

from by_your_command.audio.pcm import read_wav
from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

# /rosout keeps a node's recent lines for late joiners: its lines from startup on, in order.
ROSOUT = QoSProfile(
    depth=1000, reliability=QoSReliabilityPolicy.RELIABLE, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL
)
PRE_ROLL_S = 15 * 512 / 16000
HANGOVER_S = 13 * 512 / 16000  # 400 ms of silence rounded up to whole frames


def node(module: str, namespace: str, *params: str) -> list[str]:
    args = ["--ros-args", "-r", f"__ns:={namespace}"]
    for param in params:
        args += ["-p", param]
    return python_module(f"by_your_command.nodes.{module}", *args)


def alive(*processes: subprocess.Popen[str]) -> Callable[[], None]:
    def check() -> None:
        for process in processes:
            if process.poll() is not None:
                output = process.stdout.read() if process.stdout else ""
                raise AssertionError(f"{process.args[2]} exited with {process.returncode}:\n{output}")

    return check


def interrupt(*processes: subprocess.Popen[str]) -> None:
    """Stop nodes with SIGINT (run_node stops them cleanly, publishing what they must first)."""
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass  # running_process escalates to SIGKILL


def spin_until(
    probe: Probe, check: Callable[[], None], condition: Callable[[], object], **kw: object
) -> None:
    def step() -> object:
        check()
        probe.spin(0.02)
        return condition()

    wait_for(step, **kw)  # type: ignore[arg-type]


@pytest.mark.ros
def test_file_to_recorder_writes_one_file_per_utterance(ros_namespace: str, tmp_path: Path) -> None:
    session = next(s for s in sessions() if s.name == "clean_en_us")
    out_dir = tmp_path / "recordings"
    recorder_cmd = node("voice_chunk_recorder", ros_namespace, f"output_dir:={out_dir}")
    vad_cmd = node("silero_vad_node", ros_namespace, "min_silence_duration_ms:=400", "input_topic:=audio")
    with (
        probe_node(ros_namespace) as probe,
        running_process(recorder_cmd) as recorder,
        running_process(vad_cmd) as vad,
    ):
        check = alive(recorder, vad)
        chunks = probe.listen(AudioDataUtterance, "prompt_voice", RELIABLE)
        activity = probe.listen(Bool, "voice_activity", RELIABLE)
        states = probe.listen(String, "attention_state", LATCHED)
        done = probe.listen(Bool, "file_audio_done", LATCHED)
        played = probe.listen(AudioChunk, "audio", STREAM)
        graph = probe.node

        def wired() -> bool:
            return (
                graph.count_subscribers(probe.topic("audio")) >= 2  # the VAD and this probe
                and graph.count_subscribers(probe.topic("prompt_voice")) >= 2
                and bool(states)
            )

        spin_until(probe, check, wired, timeout=30, what="the VAD and the recorder to discover each other")
        assert states[-1].data == "awake"
        publisher_cmd = node(
            "file_audio_publisher",
            ros_namespace,
            f"files:=[{session.path}]",
            # Faster than real time (the stamps must still follow the file's own timeline), but
            # only 2x: a block lost to a stalled process is a gap, and a gap drops the pre-roll.
            "rate_factor:=2.0",
            # 100 ms chunks: a publisher tick late under load bursts fewer chunks than the
            # subscribers' queues hold
            "chunk_samples:=1600",
            "lead_silence_ms:=1000",
            "min_subscribers:=2",  # the VAD and this probe, as the publisher's writer sees them
        )
        with running_process(publisher_cmd) as publisher:
            check_all = alive(recorder, vad)
            spin_until(
                probe,
                check_all,
                lambda: any(d.data for d in done) or publisher.poll() is not None,
                timeout=30,
                what="the file to be played",
            )
            assert publisher.poll() is None, publisher.stdout.read() if publisher.stdout else ""
            expected = len(session.segments)
            spin_until(
                probe,
                check_all,
                lambda: (
                    len(list(out_dir.glob("utterance_*.wav"))) >= expected
                    and sum(c.is_utterance_end for c in chunks) >= expected
                    # voice_activity is another topic: its last False may come after the chunks
                    and len(activity) >= 2 * expected
                ),
                timeout=60,  # the VAD may still work through a backlog on a loaded machine
                what=f"{expected} utterance files",
            )
            interrupt(publisher, vad, recorder)

    files = sorted(out_dir.glob("utterance_*.wav"))
    assert len(files) == expected, [f.name for f in files]
    # Played 2x faster, the file's stamps still follow its own timeline: consecutive chunks are
    # whole chunk durations apart (best effort may lose some), never compressed into fake gaps.
    stamps_ms = [m.header.stamp.sec * 1000 + m.header.stamp.nanosec / 1e6 for m in played]
    steps = [later - earlier for earlier, later in zip(stamps_ms, stamps_ms[1:], strict=False)]
    assert len(steps) > 10 and all(abs(step / 100 - round(step / 100)) < 0.01 and step > 0 for step in steps)
    assert [m.data for m in activity] == [True, False] * expected
    by_id: dict[int, list[AudioDataUtterance]] = {}
    for chunk in chunks:
        by_id.setdefault(chunk.utterance_id, []).append(chunk)
    assert len(by_id) == expected
    durations = {}
    for utterance_id, parts in by_id.items():
        assert [p.chunk_sequence for p in parts] == list(range(len(parts)))
        assert [p.is_utterance_end for p in parts] == [False] * (len(parts) - 1) + [True]
        assert {p.sample_rate for p in parts} == {16000}
        durations[utterance_id] = sum(len(p.int16_data) for p in parts) / 16000
    for path, (utterance_id, seconds), truth in zip(
        files, sorted(durations.items()), session.segments, strict=True
    ):
        assert path.name.startswith(f"utterance_{utterance_id}_")
        pcm, rate, channels = read_wav(path)
        assert (rate, channels) == (16000, 1)
        assert len(pcm) / 16000 == pytest.approx(seconds)
        spoken = truth.end - truth.start
        # pre-roll + speech + hangover, with Silero's onset/offset tolerance
        assert spoken + PRE_ROLL_S + HANGOVER_S - 0.25 <= seconds <= spoken + PRE_ROLL_S + HANGOVER_S + 0.35
        assert np.abs(pcm).max() > 1000


class VadUnderTest:
    """A silero_vad_node process, its topics, and its own ordered log (/rosout) of what it did."""

    def __init__(self, probe: Probe, vad: subprocess.Popen[str], namespace: str) -> None:
        self.probe = probe
        self.check = alive(vad)
        self.states = probe.listen(String, "attention_state", LATCHED)
        self.chunks = probe.listen(AudioDataUtterance, "prompt_voice", RELIABLE)
        logger = f"{namespace.strip('/')}.silero_vad_node"
        self._log: list[str] = []
        probe.node.create_subscription(
            Log, "/rosout", lambda m: self._log.append(m.msg) if m.name == logger else None, ROSOUT
        )
        self.text = probe.node.create_publisher(String, "prompt_text", RELIABLE)
        self.wake = probe.node.create_publisher(Bool, "wake_cmd", RELIABLE)
        self.voice_active = probe.node.create_publisher(Bool, "voice_active", RELIABLE)
        self.audio = probe.node.create_publisher(AudioChunk, "audio", STREAM)
        self.wait(
            lambda: (
                self.states
                and self.text.get_subscription_count()
                and self.wake.get_subscription_count()
                and self.voice_active.get_subscription_count()
                and self.audio.get_subscription_count()
            ),
            "the VAD node to come up",
        )
        self._mark = 0

    def wait(self, condition: Callable[[], object], what: str) -> None:
        spin_until(self.probe, self.check, condition, timeout=15, what=what)

    def mark(self) -> None:
        """Start a new record of decisions (phrases heard, attention changes) from here."""
        self._mark = len(self._log)

    def decisions(self) -> list[str]:
        """In the order the node made them: "wake"/"sleep" for phrases heard, "-> state" for changes."""
        result = []
        for line in self._log[self._mark :]:
            if line.endswith("phrase heard in prompt_text"):
                result.append(line.split("'")[1])
            elif line.startswith("attention: "):
                result.append("-> " + line.removeprefix("attention: "))
        return result

    def wait_for_decisions(self, count: int, what: str) -> list[str]:
        self.wait(lambda: len(self.decisions()) >= count, what)
        return self.decisions()


@pytest.fixture
def vad_node(ros_namespace: str) -> Iterator[VadUnderTest]:
    with (
        probe_node(ros_namespace) as probe,
        running_process(node("silero_vad_node", ros_namespace, "input_topic:=audio")) as vad,
    ):
        yield VadUnderTest(probe, vad, ros_namespace)


@pytest.mark.ros
def test_only_whole_commands_on_prompt_text_change_attention(vad_node: VadUnderTest) -> None:
    """Each sentence below holds a wake or sleep word; with matching anywhere in the text the
    node flipped state on them. The node's own ordered record shows every decision it made."""
    vad = vad_node
    assert vad.wait_for_decisions(1, "the initial state") == ["-> awake"]
    vad.mark()
    for text in [
        "I can't sleep",
        "wake up",  # a real command, but already awake: heard, no change
        "How did you sleep?",
        "Don't go to sleep!",
        "I am awake",
        "Please go to sleep now.",
        "don't wake the baby",
        "It's time to go to sleep",
        "Wake up!",
    ]:
        vad.text.publish(String(data=text))
    expected = ["wake", "sleep", "-> asleep", "wake", "-> awake"]
    assert vad.wait_for_decisions(len(expected), "the commands to be handled") == expected
    vad.wait(lambda: vad.states[-1].data == "awake", "attention_state awake")
    assert [s.data for s in vad.states][-1] == "awake" and vad.chunks == []


@pytest.mark.ros
def test_wake_while_muted_is_remembered_not_obeyed(vad_node: VadUnderTest) -> None:
    """Mute wins over wake: phrases while muted change nothing visible, and unmuting returns to
    the state they asked for (starting asleep, so a forgotten wake would show)."""
    vad = vad_node
    assert vad.wait_for_decisions(1, "the initial state") == ["-> awake"]
    vad.mark()
    vad.wake.publish(Bool(data=False))
    assert vad.wait_for_decisions(1, "wake_cmd False") == ["-> asleep"]
    vad.mark()
    vad.voice_active.publish(Bool(data=False))
    assert vad.wait_for_decisions(1, "voice_active False") == ["-> muted"]
    vad.mark()
    for text in ["wake up", "go to sleep", "wake up"]:
        vad.text.publish(String(data=text))
    vad.wait_for_decisions(3, "the three phrases to be heard while muted")
    vad.voice_active.publish(Bool(data=True))
    assert vad.wait_for_decisions(4, "unmuting") == ["wake", "sleep", "wake", "-> awake"]
    vad.wait(lambda: vad.states[-1].data == "awake", "attention_state awake")


@pytest.mark.ros
def test_audio_that_stops_mid_utterance_still_gets_its_end(vad_node: VadUnderTest) -> None:
    """Mic unplugged, echo gate shut: audio_timeout_ms closes the utterance."""
    vad = vad_node
    # (from 0.5 s: half a second of silence first, in case the node matches us a little late)
    speech = next(s for s in sessions() if s.name == "clean_en_us").audio()[8000 : 16000 * 2]
    for offset in range(0, len(speech), 512):
        vad.audio.publish(make_audio_chunk(speech[offset : offset + 512], 16000, 1))
        vad.probe.spin(0.002)
    vad.wait(lambda: any(c.is_utterance_end for c in vad.chunks), "end chunk")
    chunks = vad.chunks
    assert [c.chunk_sequence for c in chunks] == list(range(len(chunks)))
    assert [c.is_utterance_end for c in chunks].count(True) == 1 and chunks[-1].is_utterance_end
