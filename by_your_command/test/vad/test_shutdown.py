"""Stopping nodes (nodes/_runtime.run_node) in real processes on a real rclpy graph: what a node
publishes while stopping still arrives, a stuck stop yields to a second signal, a dying
executor thread ends the process."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance
from byc_testing import python_module, running_process, wait_for
from ros_probe import Probe, probe_node
from std_msgs.msg import Bool, String
from vad.corpus import sessions

from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

NS = 1_000_000_000
RUNTIME_NODES = Path(__file__).with_name("runtime_nodes.py")


def ros_args(namespace: str, *params: str) -> list[str]:
    args = ["--ros-args", "-r", f"__ns:={namespace}"]
    for param in params:
        args += ["-p", param]
    return args


def output(process: subprocess.Popen[str]) -> str:
    return process.stdout.read() if process.stdout else ""


def exited(process: subprocess.Popen[str]) -> bool:
    return process.poll() is not None


def spin_until(probe: Probe, condition: object, process: subprocess.Popen[str] | None, what: str) -> None:
    def step() -> object:
        if process is not None and exited(process):
            raise AssertionError(f"{process.args} exited with {process.returncode}:\n{output(process)}")
        probe.spin(0.02)
        return condition() if callable(condition) else condition

    wait_for(step, timeout=30, what=what)


@pytest.mark.ros
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_stopping_mid_utterance_still_delivers_its_end(ros_namespace: str, signum: int) -> None:
    """The end marker and voice_activity False go out before the context shuts down
    (before, rclpy's signal handler shut it down first and both were lost)."""
    vad_cmd = python_module(
        "by_your_command.nodes.silero_vad_node",
        *ros_args(
            ros_namespace,
            "input_topic:=audio",
            "audio_timeout_ms:=600000",  # only the signal may close the utterance
            "min_silence_duration_ms:=5000",
        ),
    )
    with probe_node(ros_namespace) as probe, running_process(vad_cmd) as vad:
        chunks = probe.listen(AudioDataUtterance, "prompt_voice", RELIABLE)
        activity = probe.listen(Bool, "voice_activity", RELIABLE)
        states = probe.listen(String, "attention_state", LATCHED)
        audio = probe.node.create_publisher(AudioChunk, "audio", STREAM)
        spin_until(
            probe,
            lambda: (
                states
                and audio.get_subscription_count()
                and probe.node.count_publishers(probe.topic("prompt_voice"))
            ),
            vad,
            "the VAD node to come up",
        )
        speech = next(s for s in sessions() if s.name == "clean_en_us").audio()[int(0.5 * 16000) : 3 * 16000]
        start_ns = 1_700_000_000 * NS
        for offset in range(0, len(speech), 512):
            sec, nanosec = divmod(start_ns + offset * NS // 16000, NS)
            audio.publish(
                make_audio_chunk(speech[offset : offset + 512], 16000, 1, Time(sec=sec, nanosec=nanosec))
            )
            probe.spin(0.002)
        spin_until(probe, lambda: any(a.data for a in activity) and chunks, vad, "the utterance to start")
        assert not any(c.is_utterance_end for c in chunks)
        vad.send_signal(signum)
        spin_until(probe, lambda: exited(vad), None, "the VAD to exit")
        assert vad.returncode == 0, output(vad)
        spin_until(
            probe,
            lambda: any(c.is_utterance_end for c in chunks) and not activity[-1].data,
            None,
            "the end marker and voice_activity False sent while stopping",
        )
    assert [a.data for a in activity] == [True, False]
    assert [c.chunk_sequence for c in chunks] == list(range(len(chunks)))
    assert [c.is_utterance_end for c in chunks] == [False] * (len(chunks) - 1) + [True]
    assert len({c.utterance_id for c in chunks}) == 1


@pytest.mark.ros
def test_a_second_signal_ends_a_stop_that_hangs(ros_namespace: str) -> None:
    command = [sys.executable, str(RUNTIME_NODES), "stuck", *ros_args(ros_namespace)]
    with probe_node(ros_namespace) as probe, running_process(command) as stuck:
        states = probe.listen(String, "runtime_state", LATCHED)
        spin_until(probe, lambda: states and states[-1].data == "running", stuck, "the node to run")
        stuck.send_signal(signal.SIGTERM)
        spin_until(probe, lambda: states[-1].data == "stopping", stuck, "before_shutdown to start")
        stuck.send_signal(signal.SIGTERM)
        spin_until(probe, lambda: exited(stuck), None, "the second signal to end the process")
        text = output(stuck)
        assert stuck.returncode == 128 + signal.SIGTERM, text
        assert "second SIGTERM" in text, text
        assert "in before_shutdown" in text, text  # where the stop was stuck


def stuck_node(namespace: str, duplicate_window_s: float, stop_deadline_s: float = 3600.0) -> list[str]:
    """The stuck node, with stop_signals' window for a repeated SIGINT and run_node's stop deadline
    set (no timing in the test)."""
    code = (
        "import runpy, sys\n"
        "import by_your_command.stop_signals as stop_signals\n"
        "import by_your_command.nodes._runtime as runtime\n"
        "stop_signals.DUPLICATE_WINDOW_S = float(sys.argv[1])\n"
        "runtime.STOP_DEADLINE_S = float(sys.argv[2])\n"
        "sys.argv = sys.argv[3:]\n"
        "runpy.run_path(sys.argv[0], run_name='__main__')\n"
    )
    return [
        sys.executable,
        "-c",
        code,
        str(duplicate_window_s),
        str(stop_deadline_s),
        str(RUNTIME_NODES),
        "stuck",
        *ros_args(namespace),
    ]


@pytest.mark.ros
def test_a_stop_stuck_past_its_deadline_ends_and_says_where(ros_namespace: str) -> None:
    """Teardown (rclpy, DDS) can hang where no bound of ours reaches: with one signal only, the
    process still ends, non-zero, with the stack of the stuck step (here before_shutdown)."""
    with probe_node(ros_namespace) as probe, running_process(stuck_node(ros_namespace, 0.0, 1.0)) as stuck:
        states = probe.listen(String, "runtime_state", LATCHED)
        spin_until(probe, lambda: states and states[-1].data == "running", stuck, "the node to run")
        stuck.send_signal(signal.SIGTERM)
        spin_until(probe, lambda: exited(stuck), None, "the stuck stop to end by itself")
        text = output(stuck)
        assert stuck.returncode == 1, text
        assert "in before_shutdown" in text, text


@pytest.mark.ros
@pytest.mark.parametrize(
    "window_s, then, status",
    [(3600.0, signal.SIGTERM, 128 + signal.SIGTERM), (0.0, None, 128 + signal.SIGINT)],
    ids=["copy-of-the-ctrl-c", "ctrl-c-again-later"],
)
def test_a_sigint_repeated_at_once_is_the_same_stop(
    ros_namespace: str, window_s: float, then: int | None, status: int
) -> None:
    """Under `ros2 launch`, one Ctrl-C arrives twice (the terminal's, then launch's): the copy must
    not end the orderly stop; launch's SIGTERM escalation, or a Ctrl-C after the window, still does."""
    with probe_node(ros_namespace) as probe, running_process(stuck_node(ros_namespace, window_s)) as stuck:
        states = probe.listen(String, "runtime_state", LATCHED)
        spin_until(probe, lambda: states and states[-1].data == "running", stuck, "the node to run")
        stuck.send_signal(signal.SIGINT)
        spin_until(probe, lambda: states[-1].data == "stopping", stuck, "before_shutdown to start")
        stuck.send_signal(signal.SIGINT)
        if then is not None:
            stuck.send_signal(then)  # handled after the SIGINT: the lower signal number goes first

        def escalated_and_exited() -> bool:
            # A signal sent while another is still pending for the main thread may be taken by
            # another thread, which does not wake the main thread's wait (seen once in CI under
            # load): the escalation is sent again until the process has gone.
            if then is not None and not exited(stuck):
                stuck.send_signal(then)
            return exited(stuck)

        spin_until(probe, escalated_and_exited, None, "the process to exit")
        text = output(stuck)
        assert stuck.returncode == status, text
        assert ("SIGINT again right away" in text) == (then is not None), text


@pytest.mark.ros
def test_an_exception_in_a_callback_ends_the_process_with_an_error(ros_namespace: str) -> None:
    command = [sys.executable, str(RUNTIME_NODES), "crash", *ros_args(ros_namespace)]
    with running_process(command) as crashing:
        wait_for(lambda: exited(crashing), timeout=30, what="the process to exit by itself")
        text = output(crashing)
        assert crashing.returncode == 1, text
        assert "executor thread died: RuntimeError: callback failed on purpose" in text
