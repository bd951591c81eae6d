"""Run a graph's processes together: prefixed logs, one dies -> all stop, Ctrl-C -> all stop.

One thread, one selector: every child's output pipe and a self-pipe that signal handlers write to
(`signal.set_wakeup_fd`), so a signal or a line of output wakes the loop at once and nothing is
shared between threads. Children run in their own sessions: a terminal's Ctrl-C reaches only this
process, which then stops each child's process group with SIGTERM, and SIGKILL after the deadline
(a hung rclpy process can ignore SIGTERM). A second Ctrl-C kills at once.
"""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from types import FrameType
from typing import TextIO

from by_your_command.graph.processes import ProcessSpec

# Exit statuses that mean "stopped because we asked": run_node exits 0, a plain process dies of the signal.
_CLEAN_STOP = (0, -signal.SIGTERM, -signal.SIGINT)
_SELF = "byc up"


@dataclass(frozen=True)
class SupervisorConfig:
    # SIGTERM -> SIGKILL. run_node's own budget is 5 s to stop the executor + 2 s for acks + the
    # node's teardown (the VAD's wake worker: 2 s): on a loaded machine that passed 10 s.
    stop_timeout_s: float = 20.0
    poll_interval_s: float = 0.2  # also how often exits are checked when no output arrives


class _Child:
    def __init__(self, spec: ProcessSpec, process: subprocess.Popen[bytes]) -> None:
        self.spec = spec
        self.process = process
        self.partial = b""
        self.stopped_by_us = False
        self.killed = False
        self.reported = False


class Supervisor:
    def __init__(
        self,
        processes: Sequence[ProcessSpec],
        out: TextIO,
        env: Mapping[str, str] | None = None,
        config: SupervisorConfig = SupervisorConfig(),
    ) -> None:
        self._specs = list(processes)
        self._out = out
        self._env = {**os.environ, **(env or {}), "PYTHONUNBUFFERED": "1"}
        self._config = config
        self._width = max((len(spec.name) for spec in self._specs), default=0)
        self._children: list[_Child] = []
        self._selector = selectors.DefaultSelector()
        self._signals = 0
        self._stopping = False
        self._deadline = 0.0
        self._died: list[str] = []  # "name (exit status N)" of processes that ended on their own
        self._unclean: list[str] = []

    # -- output ---------------------------------------------------------------------------------

    def say(self, text: str) -> None:
        self._emit(_SELF, text)

    def _emit(self, name: str, line: str) -> None:
        self._out.write(f"[{name:<{self._width}}] {line}\n")
        self._out.flush()

    def _read(self, child: _Child) -> None:
        fd = child.process.stdout.fileno() if child.process.stdout else -1
        data = os.read(fd, 65536)
        if not data:
            self._selector.unregister(fd)
            if child.partial:
                self._emit(child.spec.name, child.partial.decode(errors="replace"))
                child.partial = b""
            return
        *lines, child.partial = (child.partial + data).split(b"\n")
        for line in lines:
            self._emit(child.spec.name, line.decode(errors="replace").rstrip("\r"))

    # -- signals --------------------------------------------------------------------------------

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self._signals += 1  # the loop acts on it: the wakeup fd makes select() return

    # -- lifecycle ------------------------------------------------------------------------------

    def run(self) -> int:
        """Start everything, supervise until a signal or a death, stop the rest; the exit status."""
        wake_read, wake_write = os.pipe()
        os.set_blocking(wake_read, False)
        os.set_blocking(wake_write, False)
        self._selector.register(wake_read, selectors.EVENT_READ)
        previous_fd = signal.set_wakeup_fd(wake_write)
        previous = {sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            self._start_all()
            if not self._stopping:
                self.say(f"{len(self._children)} processes running; Ctrl-C stops them all")
            self._loop(wake_read)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            signal.set_wakeup_fd(previous_fd)
            self._selector.close()
            os.close(wake_read)
            os.close(wake_write)
        return self._summary()

    def _start_all(self) -> None:
        for spec in self._specs:
            if self._signals:
                self._begin_stop("stop requested while starting")
                return
            try:
                process = subprocess.Popen(
                    spec.argv,
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.PIPE,
                    stderr=subprocess.STDOUT,
                    env=self._env,
                    start_new_session=True,  # our own Ctrl-C handling, and a group to signal
                )
            except OSError as error:
                self._died.append(f"{spec.name} (cannot start: {error})")
                self._begin_stop(f"cannot start {spec.name}: {error}")
                return
            child = _Child(spec, process)
            self._children.append(child)
            assert process.stdout is not None
            self._selector.register(process.stdout.fileno(), selectors.EVENT_READ, child)
            self.say(f"started {spec.name} (pid {process.pid}): {' '.join(spec.argv)}")

    def _loop(self, wake_read: int) -> None:
        while True:
            for key, _ in self._selector.select(timeout=self._config.poll_interval_s):
                if key.fileobj == wake_read:
                    try:
                        os.read(wake_read, 512)
                    except BlockingIOError:
                        pass
                else:
                    self._read(key.data)
            if self._signals and not self._stopping:
                self._begin_stop("stop requested")
            if self._signals > 1:
                self._kill_remaining("second stop request")
            self._check_exits()
            if self._stopping and time.monotonic() > self._deadline:
                self._kill_remaining(f"still running {self._config.stop_timeout_s:g} s after SIGTERM")
            if all(c.reported for c in self._children) and (self._stopping or not self._children):
                self._drain()
                return

    def _check_exits(self) -> None:
        for child in self._children:
            status = child.process.poll()
            if status is None or child.reported:
                continue
            child.reported = True
            name = child.spec.name
            if not child.stopped_by_us:
                self._died.append(f"{name} (exit status {status})")
                self._begin_stop(f"{name} exited with status {status}: stopping the others")
            elif child.killed or status not in _CLEAN_STOP:
                self._unclean.append(f"{name} (exit status {status})")
                self.say(f"{name} stopped uncleanly (exit status {status})")
            else:
                self.say(f"{name} stopped")

    def _begin_stop(self, reason: str) -> None:
        if self._stopping:
            return
        self._stopping = True
        self._deadline = time.monotonic() + self._config.stop_timeout_s
        self.say(f"{reason}; sending SIGTERM")
        for child in self._children:
            if child.process.poll() is None:
                child.stopped_by_us = True
                self._signal_group(child, signal.SIGTERM)

    def _kill_remaining(self, reason: str) -> None:
        for child in self._children:
            if child.process.poll() is None and not child.killed:
                child.killed = child.stopped_by_us = True
                self.say(f"{child.spec.name}: {reason}: SIGKILL")
                self._signal_group(child, signal.SIGKILL)

    @staticmethod
    def _signal_group(child: _Child, signum: int) -> None:
        try:
            os.killpg(child.process.pid, signum)  # the group: whatever the child started goes too
        except ProcessLookupError:
            pass

    def _drain(self) -> None:
        """Output still in the pipes after every process ended (a grandchild may hold one open)."""
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline and len(self._selector.get_map()) > 1:
            for key, _ in self._selector.select(timeout=0.05):
                if isinstance(key.data, _Child):
                    self._read(key.data)
        for child in self._children:
            if child.process.stdout:
                child.process.stdout.close()

    def _summary(self) -> int:
        if self._died:
            self.say(f"FAILED: {', '.join(self._died)} ended on its own; everything was stopped")
            return 1
        if self._unclean:
            self.say(f"stopped, but not cleanly: {', '.join(self._unclean)}")
            return 1
        self.say("all processes stopped")
        return 0
