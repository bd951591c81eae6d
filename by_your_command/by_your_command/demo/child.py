"""The demo's graph as a child `byc up` process: its output kept in a log, its failures named.

`byc up` is the supervisor (prefixed logs, one process dies -> all stop, SIGINT -> all stop); the
demo only starts it, copies its lines into a file, remembers the lines that say what went wrong,
and asks it to stop. The child runs in its own session so a terminal's Ctrl-C reaches only the
demo, which then stops the graph in order.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import signal
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TextIO

# What byc up's supervisor says when a process ended on its own, or did not stop cleanly.
_DIED = re.compile(r"^\[byc up\s*\] (\S+) exited with status (-?\d+)")
_FAILED = re.compile(r"^\[byc up\s*\] (FAILED: .*|stopped, but not cleanly: .*)$")
TAIL_LINES = 25


class ChildGraph:
    def __init__(
        self, argv: Sequence[str], log_path: Path, echo: Callable[[str], None] | None = None
    ) -> None:
        self.argv = list(argv)
        self.log_path = log_path
        self._echo = echo
        self._process: asyncio.subprocess.Process | None = None
        self._pump: asyncio.Task[None] | None = None
        self._log: TextIO | None = None
        self.tail: deque[str] = deque(maxlen=TAIL_LINES)
        self.died: list[str] = []  # "name (exit status N)" of processes that ended on their own
        self.failure_line = ""  # byc up's own last word on a failure
        self.stop_requested = False

    async def start(self) -> None:
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = self.log_path.open("w", encoding="utf-8")
        self._process = await asyncio.create_subprocess_exec(
            *self.argv,
            stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.STDOUT,
            start_new_session=True,
        )
        self._pump = asyncio.create_task(self._read(), name="byc demo: graph output")

    async def _read(self) -> None:
        process = self._process
        assert process is not None and process.stdout is not None and self._log is not None
        while True:
            raw = await process.stdout.readline()
            if not raw:
                return
            line = raw.decode(errors="replace").rstrip("\r\n")
            self._log.write(line + "\n")
            self._log.flush()
            self.tail.append(line)
            died = _DIED.match(line)
            if died and not self.stop_requested:
                self.died.append(f"{died[1]} (exit status {died[2]})")
            failed = _FAILED.match(line)
            if failed:
                self.failure_line = failed[1]
            if self._echo is not None:
                self._echo(line)

    @property
    def exited(self) -> bool:
        return self._process is not None and self._process.returncode is not None

    @property
    def returncode(self) -> int | None:
        return None if self._process is None else self._process.returncode

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    def what_failed(self) -> str:
        """The processes that died (byc up names them), else byc up's own failure line."""
        if self.died:
            return ", ".join(self.died)
        return self.failure_line or f"byc up exited with status {self.returncode}"

    async def stop(self, timeout_s: float) -> int:
        """SIGINT to byc up (it stops every process in order); SIGKILL after `timeout_s`."""
        process = self._process
        if process is None:
            return 0
        if process.returncode is None:
            self.stop_requested = True
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGINT)
            try:
                await asyncio.wait_for(process.wait(), timeout_s)
            except asyncio.TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
                await process.wait()
        await self.close()
        return process.returncode if process.returncode is not None else 1

    async def close(self) -> None:
        if self._pump is not None:
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._pump, 5.0)  # the rest of the output
            self._pump = None
        if self._log is not None:
            self._log.close()
            self._log = None
