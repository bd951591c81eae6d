"""The audio front end as separate processes on a real rclpy graph:
file_audio_publisher -> echo_suppressor (external) -> silero_vad_node -> voice_chunk_recorder."""

from __future__ import annotations

import signal
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance
from byc_testing import python_module, running_process, wait_for
from ros_probe import Probe, probe_node
from std_msgs.msg import Bool, String
from vad.corpus import sessions

from by_your_command.audio.pcm import read_wav
from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

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
    """Stop nodes with SIGINT, which rclpy handles even while its executor waits in C; SIGTERM goes
    to a Python handler (nodes/_runtime.py) that only runs when the wait ends (up to a timer period)."""
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
    vad_cmd = node("silero_vad_node", ros_namespace, "min_silence_duration_ms:=400")
    echo_cmd = node("echo_suppressor", ros_namespace, "mode:=external")
    with (
        probe_node(ros_namespace) as probe,
        running_process(recorder_cmd) as recorder,
        running_process(vad_cmd) as vad,
        running_process(echo_cmd) as echo,
    ):
        check = alive(recorder, vad, echo)
        chunks = probe.listen(AudioDataUtterance, "prompt_voice", RELIABLE)
        activity = probe.listen(Bool, "voice_activity", RELIABLE)
        states = probe.listen(String, "attention_state", LATCHED)
        done = probe.listen(Bool, "file_audio_done", LATCHED)
        graph = probe.node

        def wired() -> bool:
            return (
                graph.count_publishers(probe.topic("audio_filtered")) >= 1
                and graph.count_subscribers(probe.topic("audio_filtered")) >= 1
                and graph.count_subscribers(probe.topic("prompt_voice")) >= 2
                and bool(states)
            )

        spin_until(
            probe, check, wired, timeout=30, what="echo_suppressor, VAD and recorder to discover each other"
        )
        assert states[-1].data == "awake"
        publisher_cmd = node(
            "file_audio_publisher",
            ros_namespace,
            f"files:=[{session.path}]",
            "rate_factor:=3.0",
            "lead_silence_ms:=1000",
        )
        with running_process(publisher_cmd) as publisher:
            check_all = alive(recorder, vad, echo)
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
                ),
                timeout=15,
                what=f"{expected} utterance files",
            )
            interrupt(publisher, echo, vad, recorder)

    files = sorted(out_dir.glob("utterance_*.wav"))
    assert len(files) == expected, [f.name for f in files]
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


@pytest.mark.ros
def test_sleep_wake_and_mute_are_latched_and_gate_the_audio(ros_namespace: str) -> None:
    with (
        probe_node(ros_namespace) as probe,
        running_process(node("silero_vad_node", ros_namespace, "input_topic:=audio")) as vad,
    ):
        check = alive(vad)
        states = probe.listen(String, "attention_state", LATCHED)
        chunks = probe.listen(AudioDataUtterance, "prompt_voice", RELIABLE)
        text = probe.node.create_publisher(String, "prompt_text", RELIABLE)
        wake = probe.node.create_publisher(Bool, "wake_cmd", RELIABLE)
        voice_active = probe.node.create_publisher(Bool, "voice_active", RELIABLE)
        audio = probe.node.create_publisher(AudioChunk, "audio", STREAM)
        spin_until(
            probe,
            check,
            lambda: (
                states
                and text.get_subscription_count()
                and wake.get_subscription_count()
                and voice_active.get_subscription_count()
                and audio.get_subscription_count()
            ),
            timeout=30,
            what="the VAD node to come up",
        )

        def expect(state: str) -> None:
            spin_until(
                probe, check, lambda: states[-1].data == state, timeout=10, what=f"attention_state {state}"
            )

        expect("awake")
        text.publish(String(data="Please go to sleep now."))
        expect("asleep")
        text.publish(String(data="I am awake"))  # not a wake phrase: a substring only
        wake.publish(Bool(data=True))
        expect("awake")
        assert [s.data for s in states][-3:] == ["awake", "asleep", "awake"]
        voice_active.publish(Bool(data=False))
        expect("muted")
        text.publish(String(data="wake up"))  # mute wins over wake
        voice_active.publish(Bool(data=True))
        expect("awake")
        assert "muted" in [s.data for s in states] and chunks == []

        # Speech that stops arriving mid-utterance (mic unplugged, echo gate shut) still gets its end.
        # (from 0.5 s: half a second of silence first, in case the node matches us a little late)
        speech = next(s for s in sessions() if s.name == "clean_en_us").audio()[8000 : 16000 * 2]
        for offset in range(0, len(speech), 512):
            audio.publish(make_audio_chunk(speech[offset : offset + 512], 16000, 1))
            probe.spin(0.002)
        spin_until(
            probe, check, lambda: any(c.is_utterance_end for c in chunks), timeout=10, what="end chunk"
        )
        assert [c.chunk_sequence for c in chunks] == list(range(len(chunks)))
        assert [c.is_utterance_end for c in chunks].count(True) == 1 and chunks[-1].is_utterance_end
