"""Runs the stop spotter on its own thread: the VAD node's executor only queues blocks.

A bounded queue (`max_blocks`, ~6 s of 32 ms blocks) sits between them: if decoding falls that far
behind, the oldest blocks are dropped and counted (the spotter's timeline restarts at the gap).
A spotter exception is counted and reported, and the worker goes on: the safety stop never dies
unseen.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from by_your_command.audio.pcm import Int16Array
from by_your_command.safety.spotter import Detection, StopSpotter

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Block:
    reference: bool  # audio_played (else the microphone)
    pcm: Int16Array
    sample_rate: int
    channels: int
    start_ns: int


class SpotterWorker:
    def __init__(
        self,
        spotter: StopSpotter,
        on_stop: Callable[[Detection], None],
        on_error: Callable[[Exception], None],
        max_blocks: int = 200,
    ) -> None:
        self.spotter = spotter
        self._on_stop = on_stop
        self._on_error = on_error
        self._queue: deque[_Block] = deque()
        self._max = max_blocks
        self._cv = threading.Condition()
        self._closed = False
        self.blocks = 0
        self.dropped = 0
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name="safety_stop", daemon=True)
        self._thread.start()

    def mic(self, pcm: Int16Array, sample_rate: int, channels: int, start_ns: int) -> None:
        self._put(_Block(False, pcm, sample_rate, channels, start_ns))

    def reference(self, pcm: Int16Array, sample_rate: int, channels: int, start_ns: int) -> None:
        self._put(_Block(True, pcm, sample_rate, channels, start_ns))

    def _put(self, block: _Block) -> None:
        with self._cv:
            if len(self._queue) >= self._max:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(block)
            self._cv.notify()

    def idle(self) -> bool:
        """Nothing queued (for tests and benchmarks)."""
        with self._cv:
            return not self._queue and not self._busy

    _busy = False

    def close(self, timeout: float = 2.0) -> None:
        with self._cv:
            self._closed = True
            self._queue.clear()
            self._cv.notify()
        self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._queue and not self._closed:
                    self._cv.wait()
                if self._closed:
                    return
                block = self._queue.popleft()
                self._busy = True
            try:
                self._process(block)
            except Exception as error:  # a bad block or a decoder failure must not end the safety stop
                self.errors += 1
                try:
                    self._on_error(error)
                except Exception:
                    log.exception("safety stop error callback failed")
            finally:
                self._busy = False

    def _process(self, block: _Block) -> None:
        self.blocks += 1
        if block.reference:
            self.spotter.reference(block.pcm, block.sample_rate, block.channels, block.start_ns)
            return
        for detection in self.spotter.mic(block.pcm, block.sample_rate, block.channels, block.start_ns):
            self._on_stop(detection)
