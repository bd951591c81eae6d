"""Time for the agent runtime, injectable so tests run on virtual time."""

from __future__ import annotations

import asyncio
import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float:
        """Monotonic seconds: deadlines, durations, latencies."""

    def wall(self) -> float:
        """Seconds since the epoch: message stamps and ids only, never durations."""

    async def sleep(self, seconds: float) -> None: ...


class LoopClock:
    """The running event loop's clock (asyncio's own timers use it too, so deadlines agree)."""

    def now(self) -> float:
        return asyncio.get_running_loop().time()

    def wall(self) -> float:
        return time.time()

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(seconds)
