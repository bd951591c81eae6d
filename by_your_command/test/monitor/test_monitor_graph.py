"""The monitor page in headless Chromium on a real graph: `byc up offline` fed by the file audio
publisher (the bundled speech), a frame_forwarder fed by a test camera, and the offline agent."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from browser_helpers import transcript, wait_page
from byc_testing import INSTALL_LIB, running_process, wait_for
from cdp import Browser, Page
from ros_probe import probe_node
from sensor_msgs.msg import Image
from std_msgs.msg import String

from by_your_command.demo import bundled_speech
from by_your_command.nodes import _qos

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(300)]

GRAPH_TIMEOUT_S = 150  # the 27 s file and the agent's answers on a loaded 2-core machine, with room to spare
START_TOPIC = "monitor_test_start"
CAMERA_PERIOD_S = 0.2  # the test camera's frame rate (5 fps), like a slow real camera


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def accepting(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1):
            return True
    except OSError:
        return False


@contextmanager
def fake_camera(namespace: str) -> Iterator[None]:
    """Publishes rgb8 frames on camera/image_raw and a detections message for them until closed."""
    stop = threading.Event()
    with probe_node(namespace, "test_camera") as probe:
        images = probe.node.create_publisher(Image, "camera/image_raw", _qos.STREAM)
        detections = probe.node.create_publisher(String, "detections", _qos.RELIABLE)
        pixels = np.zeros((96, 128, 3), dtype=np.uint8)
        pixels[:, :, 2] = 180  # blue, with a grey square where the "cup" is
        pixels[24:72, 32:80] = 200
        found = {
            "frame_id": "camera",
            "width": 128,
            "height": 96,
            "detections": [
                {"label": "test cup", "box": [32, 24, 80, 72], "box_2d": [250, 250, 750, 625], "score": None}
            ],
        }

        def run() -> None:
            while not stop.wait(CAMERA_PERIOD_S):  # a camera's frame period, not a wait on a result
                stamp = probe.node.get_clock().now().to_msg()
                frame = Image(height=96, width=128, encoding="rgb8", step=128 * 3, data=pixels.tobytes())
                frame.header.stamp, frame.header.frame_id = stamp, "camera"
                images.publish(frame)
                detections.publish(
                    String(data=json.dumps({**found, "stamp": stamp.sec + stamp.nanosec * 1e-9}))
                )

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join(timeout=5)


class Output:
    """Reads a process's output on a thread: a full pipe would stall the process (byc up logs a lot)."""

    def __init__(self, process: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        threading.Thread(target=self._pump, args=(process,), daemon=True).start()

    def _pump(self, process: subprocess.Popen[str]) -> None:
        assert process.stdout is not None
        for line in process.stdout:
            self.lines.append(line.rstrip("\n"))

    def tail(self, n: int = 60) -> str:
        return "\n".join(self.lines[-n:])


def count(lines: list[tuple[str, str]], kind: str, predicate: object = None) -> int:
    return sum(1 for k, text in lines if k == kind and (predicate is None or predicate(text)))  # type: ignore[operator]


def test_the_monitor_follows_the_offline_graph_and_drives_it(
    browser: Browser,
    ros_namespace: str,
    tmp_path: Path,
) -> None:
    port = free_port()
    up = [
        sys.executable,
        "-m",
        "by_your_command.cli.up",
        "offline",
        "--namespace",
        ros_namespace.strip("/"),
        "--set",
        f"audio_source=file:{bundled_speech()}",
        "--set",
        f"audio_sink=wav:{tmp_path / 'robot_said.wav'}",
        "--set",
        f"bridge_port={port}",
        # The speech starts when this test says so (a subscriber on START_TOPIC), once the page and the
        # agent are connected: the bridge subscribes prompt_voice at its own start, so the profile's
        # own wait does not cover an agent that is slow to start on a loaded machine.
        "--set",
        f"file_audio_publisher.wait_for_topic={START_TOPIC}",
    ]
    forwarder = [str(INSTALL_LIB / "frame_forwarder"), "--ros-args", "-r", f"__ns:={ros_namespace}"]
    with running_process(up) as graph, running_process(forwarder) as frames, fake_camera(ros_namespace):
        graph_log, frames_log = Output(graph), Output(frames)
        try:
            _check_the_page(browser, graph, port, tmp_path, ros_namespace)
        except BaseException:
            print(f"--- byc up (last lines)\n{graph_log.tail()}\n--- frame_forwarder\n{frames_log.tail(20)}")
            raise


def _check_the_page(
    browser: Browser, graph: subprocess.Popen[str], port: int, tmp_path: Path, namespace: str
) -> None:
    wait_for(lambda: accepting(port) or graph.poll() is not None, timeout=90, what="the bridge's port")
    assert graph.poll() is None, "byc up ended early"
    page = browser.new_page()
    assert page.navigate(f"http://127.0.0.1:{port}/") == 200  # loopback, no token: the page is served
    wait_page(page, "document.getElementById('connection').dataset.state === 'connected'", what="connected")
    wait_page(
        page,
        "document.getElementById('agents-connected').textContent.startsWith('1 agent(s) connected')",
        timeout=120,
        what="the agent connected (agent_summary)",
    )
    with probe_node(namespace, "start_speech") as starter:
        starter.node.create_subscription(String, START_TOPIC, lambda _: None, _qos.RELIABLE)
        _follow_the_speech(browser, page, graph, tmp_path)


def _follow_the_speech(browser: Browser, page: Page, graph: subprocess.Popen[str], tmp_path: Path) -> None:
    def heard_everything() -> bool:
        lines = transcript(page)
        return (
            count(lines, "user") >= 3
            and count(lines, "robot") >= 1
            and count(lines, "latency") >= 1
            and count(lines, "played", lambda t: "stopped talking" in t) >= 1  # from playback_status
            and count(lines, "command", lambda t: t.endswith(": accepted")) >= 1
            and ("attention", "asleep") in lines
            and ("attention", "awake") in lines[lines.index(("attention", "asleep")) :]
        )

    try:
        wait_for(
            heard_everything, timeout=GRAPH_TIMEOUT_S, interval=0.5, what="the spoken session on the page"
        )
    finally:
        print("transcript on the page:", *transcript(page), sep="\n  ")
    lines = transcript(page)
    # "go to sleep" was said: the VAD fell asleep (and "wake up" woke it again).
    assert ("attention", "asleep") in lines
    assert any(kind == "command" and "accepted" in text for kind, text in lines), lines

    # The forwarded camera frame with its detection.
    wait_page(page, "Number(document.getElementById('camera-caption').dataset.frames) >= 1", what="a frame")
    wait_page(page, "document.getElementById('detections').textContent === 'test cup [32, 24, 80, 72]'")

    # The agent's row, from the bridge's agent_summary.
    wait_page(
        page,
        "Array.from(document.querySelectorAll('#agents tbody td')).slice(0, 2).map(td => td.textContent)"
        ".join(' ') === 'robot offline'",
        what="the offline agent in the agents table",
    )

    # The buttons reach the VAD, and the text box reaches the agent.
    page.evaluate("document.getElementById('mute').click()")
    wait_page(page, "document.getElementById('attention').dataset.state === 'muted'", what="muted")
    page.evaluate("document.getElementById('unmute').click()")
    wait_page(page, "document.getElementById('attention').dataset.state === 'awake'", what="unmuted")
    page.evaluate(
        "document.getElementById('prompt-input').value = 'who are you';"
        "document.getElementById('prompt-form').requestSubmit()"
    )
    wait_for(
        lambda: count(transcript(page), "robot", lambda t: "Barney" in t) >= 1,
        timeout=60,
        interval=0.5,
        what="the agent's answer to the typed prompt",
    )
    shot = page.screenshot(tmp_path / "monitor_graph.png")
    print(f"monitor screenshot: {shot}")
    browser.pump()
    assert page.errors() == []
    assert graph.poll() is None, "a graph process died"
