"""Publishing to the robot off the scheduler: the scheduler queues, a worker per lane publishes.

A slow bridge must never hold up what the scheduler decides (an interruption, a deadline), so the
scheduler only queues. Two lanes, each in order: the reply's audio (bulky, bounded in bytes), and
everything else (interruptions, commands, texts, metrics), which never waits behind audio. A queued
chunk of a stream that was cut is dropped before it is sent. Every publish has its own deadline;
what fails or does not fit is counted per topic and logged, never raised.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import Counter, deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

log = logging.getLogger(__name__)

MAX_VOICE_BYTES = 16 * 1024 * 1024  # ~5.8 min of 24 kHz audio queued before chunks are dropped
MAX_CONTROL_ITEMS = 1024
LOGGED_FAILURES = 10  # the first failures are logged each, then every 100th


@dataclass(frozen=True)
class _Job:
    what: str  # the topic's role, for counts and logs
    send: Callable[[], Awaitable[None]]  # called by the worker: no coroutine exists while queued
    stream_id: str = ""
    size: int = 0


class _Lane:
    def __init__(self, name: str) -> None:
        self.name = name
        self.jobs: deque[_Job] = deque()
        self.bytes = 0
        self.ready = asyncio.Event()
        self.drained = asyncio.Event()
        self.drained.set()


class Outbox:
    def __init__(self, agent_id: str, timeout_s: float, on_failure: Callable[[], None]) -> None:
        self._agent_id = agent_id
        self._timeout_s = timeout_s
        self._on_failure = on_failure  # the runtime's counter
        self._voice = _Lane("voice")
        self._control = _Lane("control")
        self._workers: list[asyncio.Task[None]] = []
        self.failed: Counter[str] = Counter()  # publishes that raised or timed out, per topic
        self.dropped: Counter[str] = Counter()  # never sent: no room, or their stream was cut

    @property
    def failures(self) -> int:
        return sum(self.failed.values()) + sum(self.dropped.values())

    def start(self) -> None:
        for lane in (self._voice, self._control):
            self._workers.append(asyncio.create_task(self._work(lane), name=f"{self._agent_id} {lane.name}"))

    def voice(self, stream_id: str, size: int, send: Callable[[], Awaitable[None]]) -> None:
        lane = self._voice
        if lane.bytes + size > MAX_VOICE_BYTES:
            self._drop("response_voice", "the bridge is too slow: reply audio dropped")
            return
        lane.bytes += size
        self._queue(lane, _Job("response_voice", send, stream_id, size))

    def control(self, what: str, send: Callable[[], Awaitable[None]]) -> None:
        if len(self._control.jobs) >= MAX_CONTROL_ITEMS:
            self._drop(what, "the bridge is too slow: message dropped")
            return
        self._queue(self._control, _Job(what, send))

    def discard_stream(self, stream_id: str) -> None:
        """A cut stream's queued audio is useless to the player: drop it unsent."""
        lane = self._voice
        kept = deque(job for job in lane.jobs if job.stream_id != stream_id)
        cut = len(lane.jobs) - len(kept)
        if cut:
            lane.jobs = kept
            lane.bytes = sum(job.size for job in kept)
            log.debug("agent %s: %d queued chunk(s) of cut stream %s dropped", self._agent_id, cut, stream_id)

    async def close(self, flush_timeout_s: float) -> None:
        """Send what is queued (the last metrics, a stream's end) within the timeout, then stop."""
        drained = (self._voice.drained.wait(), self._control.drained.wait())
        with contextlib.suppress(asyncio.TimeoutError):
            await asyncio.wait_for(asyncio.gather(*drained), flush_timeout_s)
        for worker in self._workers:
            worker.cancel()
        await asyncio.gather(*self._workers, return_exceptions=True)
        for lane in (self._voice, self._control):
            for job in lane.jobs:
                self.dropped[job.what] += 1
            if lane.jobs:
                log.warning("agent %s: %d message(s) not published at stop", self._agent_id, len(lane.jobs))
            lane.jobs.clear()

    def _queue(self, lane: _Lane, job: _Job) -> None:
        lane.jobs.append(job)
        lane.drained.clear()
        lane.ready.set()

    def _drop(self, what: str, why: str) -> None:
        self.dropped[what] += 1
        self._on_failure()
        self._log(what, why)

    async def _work(self, lane: _Lane) -> None:
        while True:
            if not lane.jobs:
                lane.drained.set()
                lane.ready.clear()
                await lane.ready.wait()
                continue
            job = lane.jobs.popleft()
            lane.bytes -= job.size
            try:
                await asyncio.wait_for(job.send(), self._timeout_s)
            except asyncio.CancelledError:
                raise
            except Exception as error:  # the worker never dies of one publish
                self.failed[job.what] += 1
                self._on_failure()
                self._log(job.what, repr(error))

    def _log(self, what: str, why: str) -> None:
        count = self.failures
        if count <= LOGGED_FAILURES or count % 100 == 0:
            log.warning("agent %s: could not publish %s (%d failures): %s", self._agent_id, what, count, why)
