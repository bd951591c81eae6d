"""What an OpenAI-style emulator keeps of its clients, and the URLs they reach it by (shared by the
Realtime and GPT-Live emulators)."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

JsonObject = dict[str, Any]


@dataclass(frozen=True)
class ReceivedEvent:
    connection: int  # 0 for the first connection this emulator accepted, and so on
    event: JsonObject


class EventRecord:
    """What clients sent, bounded by the size of the frames it keeps (the oldest go first)."""

    def __init__(self, max_bytes: int) -> None:
        self._events: deque[tuple[ReceivedEvent, int]] = deque()
        self._bytes, self._max_bytes = 0, max_bytes

    def add(self, event: ReceivedEvent, size: int) -> None:
        self._events.append((event, size))
        self._bytes += size
        while self._bytes > self._max_bytes and len(self._events) > 1:
            _, dropped = self._events.popleft()
            self._bytes -= dropped

    def events(self) -> list[ReceivedEvent]:
        return [event for event, _ in self._events]

    def types(self, connection: int | None = None) -> list[str]:
        return [
            str(record.event["type"])
            for record in self.events()
            if connection is None or record.connection == connection
        ]


class LoopbackUrls:
    """The emulator's URLs once it listens on `host`:`port`."""

    host: str
    port: int

    @property
    def base_url(self) -> str:
        """For `AsyncOpenAI(base_url=...)` or OPENAI_BASE_URL (the SDK turns http into ws)."""
        return f"http://{self._url_host}:{self.port}/v1"

    @property
    def websocket_base_url(self) -> str:
        """For `AsyncOpenAI(websocket_base_url=...)` (the SDK appends the API's path)."""
        return f"ws://{self._url_host}:{self.port}/v1"

    @property
    def _url_host(self) -> str:
        return f"[{self.host}]" if ":" in self.host else self.host
