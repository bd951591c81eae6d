"""An emulator served from an event loop on a daemon thread of its own, for synchronous callers
(tests and benchmarks): `_run` runs a coroutine on that loop and `_read` reads the emulator's state
there; `stop` (or leaving a `with` block) stops the emulator, then the loop."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Coroutine
from types import TracebackType
from typing import Any, Generic, Protocol, TypeVar

T = TypeVar("T")


class Stoppable(Protocol):
    async def stop(self) -> None: ...


E = TypeVar("E", bound=Stoppable)
Self = TypeVar("Self", bound="ThreadedEmulator[Any]")


class ThreadedEmulator(Generic[E]):
    """`handle` is the emulator `start` returns, started on the thread's loop."""

    def __init__(self, start: Coroutine[Any, Any, E]) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()
        self.handle: E = self._run(start)

    def _run(self, coroutine: Coroutine[Any, Any, T]) -> T:
        return asyncio.run_coroutine_threadsafe(coroutine, self._loop).result(timeout=10)

    def _read(self, read: Callable[[], T]) -> T:
        async def on_loop() -> T:
            return read()

        return self._run(on_loop())

    def stop(self) -> None:
        try:
            self._run(self.handle.stop())
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5)

    def __enter__(self: Self) -> Self:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        self.stop()
