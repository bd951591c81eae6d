"""`byc up` as a real process in a test: its output collected as it arrives, its children's pids."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from byc_testing import python_module, running_process, wait_for


class UpProcess:
    """`byc up`, or anything that logs `[<self_name>] started <name> (pid <pid>)` for each child."""

    def __init__(self, process: subprocess.Popen[str], self_name: str = "byc up") -> None:
        self.process = process
        self._started = re.compile(rf"^\[{re.escape(self_name)}\s*\] started (\S+) \(pid (\d+)\)")
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def children(self) -> dict[str, int]:
        """name -> pid of every process `byc up` said it started."""
        return {m[1]: int(m[2]) for line in self.lines if (m := self._started.match(line))}

    def lines_of(self, name: str) -> list[str]:
        return [line for line in self.lines if re.match(rf"^\[{re.escape(name)}\s*\] ", line)]

    def check_running(self) -> None:
        if self.process.poll() is not None:
            self._reader.join(5)
            raise AssertionError(f"{self.process.args} exited with {self.process.returncode}:\n{self.output}")

    def stop(self, signum: int = signal.SIGINT, timeout: float = 30) -> int:
        self.process.send_signal(signum)
        status = self.process.wait(timeout=timeout)
        self._reader.join(5)
        return status


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def wait_vad_ready(up: UpProcess) -> None:
    """Until the VAD says it is ready (or a process of the graph died: check_running raises)."""
    wait_for(
        lambda: any("VAD ready" in line for line in up.lines_of("silero_vad_node")) or up.check_running(),
        timeout=30,
        what="the VAD to be ready",
    )


def wait_for_exit(up: UpProcess, timeout: float = 30) -> int:
    status = up.process.wait(timeout=timeout)
    up._reader.join(5)
    return status


@contextmanager
def byc_up(*args: str) -> Iterator[UpProcess]:
    with running_process(python_module("by_your_command.cli.up", *args)) as process:
        up = UpProcess(process)
        try:
            yield up
        finally:
            # whatever happened, no child may outlive the test
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
                process.wait(timeout=30)
            for pid in up.children().values():
                if pid_alive(pid):
                    os.killpg(pid, signal.SIGKILL)
            wait_for(
                lambda: not any(map(pid_alive, up.children().values())), timeout=10, what="children gone"
            )


@contextmanager
def stand_in_launch(profile: str, *words: str) -> Iterator[UpProcess]:
    """`ros2 launch by_your_command <profile>.launch.py <words>` played by launch_stand_in.py, in a
    process group of its own with its children, as a terminal's foreground job is."""
    script = str(Path(__file__).with_name("launch_stand_in.py"))
    with running_process([sys.executable, script, profile, *words]) as process:
        launch = UpProcess(process, self_name="launch")
        try:
            yield launch
        finally:
            children = launch.children()
            if process.poll() is None or any(map(pid_alive, children.values())):
                with suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGKILL)  # the group: the launch and every child
            wait_for(lambda: not any(map(pid_alive, children.values())), timeout=10, what="children gone")
