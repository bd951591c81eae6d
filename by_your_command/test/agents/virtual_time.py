"""An asyncio event loop on virtual time: the clock jumps to the next timer whenever every task is idle.

Nothing waits for real: a 60 s pause costs nothing, and a test's order of events is deterministic.
`asyncio.sleep`, `wait_for` and `loop.time()` all run on this clock. If every task waits for
something that no timer can bring (a deadlock), the loop raises `Deadlock` instead of hanging.
"""

from __future__ import annotations

import asyncio
import selectors
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")

EPOCH = 1_800_000_000.0  # wall-clock seconds at virtual time 0 (so stamps look like real ones)


class Deadlock(RuntimeError):
    """Every task waits and no timer is scheduled: the code under test would hang forever."""


class _VirtualSelector(selectors.DefaultSelector):
    def __init__(self, loop: VirtualTimeLoop) -> None:
        super().__init__()
        self._loop = loop

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        ready = super().select(0)  # only the loop's self-pipe is registered in these tests
        if ready:
            return ready
        if timeout is None:
            raise Deadlock("every task is waiting and no timer is scheduled")
        self._loop.advance(timeout)
        return []


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    def __init__(self) -> None:
        self._now = 0.0
        super().__init__(_VirtualSelector(self))

    def time(self) -> float:
        return self._now

    def advance(self, seconds: float) -> None:
        self._now += max(0.0, seconds)


class VirtualClock:
    """The runtime's Clock on the virtual loop (monotonic = loop time; wall = EPOCH + loop time)."""

    def now(self) -> float:
        return asyncio.get_running_loop().time()

    def wall(self) -> float:
        return EPOCH + self.now()

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(seconds)


def run_virtual(coroutine: Coroutine[Any, Any, T], deadline_s: float | None = 3600.0) -> T:
    """Run a test coroutine on virtual time, failing it after `deadline_s` virtual seconds."""
    loop = VirtualTimeLoop()
    try:
        return loop.run_until_complete(asyncio.wait_for(coroutine, deadline_s))
    finally:
        loop.run_until_complete(loop.shutdown_asyncgens())
        loop.close()
