"""A provider's events on their way to the runtime: bounded (a slow reader makes the session wait)
and closed exactly once with an end marker every reader sees."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

from by_your_command.agents.events import ProviderEvent

_END = object()


class EventStream:
    def __init__(self, size: int) -> None:
        self._queue: asyncio.Queue[object] = asyncio.Queue(size)

    async def put(self, event: ProviderEvent) -> None:
        await self._queue.put(event)

    def put_last(self, event: ProviderEvent) -> None:
        """Queue without waiting (the session is over): drop the oldest unread event if full."""
        self._put_dropping(event)

    def end(self) -> None:
        self._put_dropping(_END)

    def _put_dropping(self, item: object) -> None:
        if self._queue.full():
            self._queue.get_nowait()
        self._queue.put_nowait(item)

    async def __aiter__(self) -> AsyncIterator[ProviderEvent]:
        while True:
            event = await self._queue.get()
            if event is _END:
                self._queue.put_nowait(_END)  # later readers end too
                return
            yield event  # type: ignore[misc]  # the queue holds ProviderEvents and _END only
