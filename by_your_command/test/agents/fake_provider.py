"""A scripted provider for the runtime's tests: no sockets, virtual time, a record of every call.

Replies are scripts: lists of (delay_s, event) steps that start when the runtime ends a turn
(end_of_turn / send_text / send_tool_results). The factory holds the scripts, so a conversation
continues across sessions the way a real one does.
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, field

from by_your_command.agents.events import (
    AssistantAudio,
    AssistantTranscript,
    ProviderEvent,
    ResponseDone,
    ResponseStatus,
    Usage,
)
from by_your_command.agents.provider import ProviderClosed, SessionSetup, ToolResult

Step = tuple[float, ProviderEvent]
Script = list[Step]
_END = object()


def tone(seconds: float, rate: int = 24000, value: int = 1000) -> bytes:
    return (value.to_bytes(2, "little", signed=True)) * int(seconds * rate)


def spoken_reply(
    response_id: str,
    seconds: float = 1.0,
    text: str = "hello there",
    rate: int = 24000,
    chunk_s: float = 0.2,
    first_after_s: float = 0.05,
    pace_s: float = 0.0,
    usage: Usage | None = None,
) -> Script:
    """Audio chunks (the first after `first_after_s`, then every `pace_s`), transcript, done."""
    item = f"item-{response_id}"
    chunks = max(1, round(seconds / chunk_s))
    steps: Script = []
    for index in range(chunks):
        pcm = tone(chunk_s, rate, value=index + 1)  # each chunk its own value: remainders are checkable
        steps.append((first_after_s if index == 0 else pace_s, AssistantAudio(response_id, item, pcm, rate)))
    steps.append((0.0, AssistantTranscript(response_id, item, text, final=True)))
    steps.append(
        (0.0, ResponseDone(response_id, ResponseStatus.COMPLETED, usage or Usage(output_audio_tokens=10)))
    )
    return steps


@dataclass
class FakeProvider:
    scripts: deque[Script]
    name: str = "fake"
    input_sample_rate: int = 24000
    max_session_s: float = 3600.0
    connect_delay_s: float = 0.0
    connect_error: BaseException | None = None
    calls: list[tuple[str, object]] = field(default_factory=list)
    audio: bytearray = field(default_factory=bytearray)
    setup: SessionSetup | None = None
    closed: bool = False
    replying: bool = True  # False: accept everything and never answer

    def __post_init__(self) -> None:
        self._events: asyncio.Queue[object] = asyncio.Queue()
        self._tasks: list[asyncio.Task[None]] = []

    # --- what tests do ---
    def emit(self, event: ProviderEvent) -> None:
        self._events.put_nowait(event)

    def drop(self) -> None:
        """The server closes the session (network drop)."""
        self._events.put_nowait(_END)

    def names(self) -> list[str]:
        return [name for name, _ in self.calls]

    # --- Provider ---
    async def connect(self, setup: SessionSetup) -> None:
        self.calls.append(("connect", setup))
        if self.connect_delay_s:
            await asyncio.sleep(self.connect_delay_s)
        if self.connect_error is not None:
            raise self.connect_error
        self.setup = setup

    def _check(self) -> None:
        if self.closed:
            raise ProviderClosed("closed")

    async def send_audio(self, pcm: bytes) -> None:
        self._check()
        self.calls.append(("audio", len(pcm)))
        self.audio += pcm

    async def end_of_turn(self) -> None:
        self._check()
        self.calls.append(("end_of_turn", len(self.audio)))
        self._answer()

    async def send_text(self, text: str) -> None:
        self._check()
        self.calls.append(("text", text))
        self._answer()

    async def add_context(self, text: str) -> None:
        self._check()
        self.calls.append(("context", text))

    async def send_image(self, jpeg: bytes) -> None:
        self._check()
        self.calls.append(("image", len(jpeg)))

    async def send_tool_results(self, results: Sequence[ToolResult]) -> None:
        self._check()
        for result in results:
            self.calls.append(("tool_result", (result.call_id, result.output)))
        self._answer()  # one reply for all of them

    async def send_tool_progress(self, call_id: str, text: str) -> None:
        self._check()
        self.calls.append(("progress", (call_id, text)))

    async def interrupt(self, response_id: str, item_id: str, played_ms: int) -> None:
        self._check()
        self.calls.append(("interrupt", (response_id, item_id, played_ms)))

    async def close(self) -> None:
        self.calls.append(("close", None))
        self.closed = True
        for task in self._tasks:
            task.cancel()
        self._events.put_nowait(_END)

    async def events(self) -> AsyncIterator[ProviderEvent]:
        while True:
            event = await self._events.get()
            if event is _END:
                return
            yield event  # type: ignore[misc]  # everything else in the queue is a ProviderEvent

    def _answer(self) -> None:
        if self.replying and self.scripts:
            self._tasks.append(asyncio.create_task(self._play(self.scripts.popleft())))

    async def _play(self, script: Script) -> None:
        for delay, event in script:
            if delay:
                await asyncio.sleep(delay)
            self.emit(event)


class FakeFactory:
    """Makes FakeProviders sharing one queue of reply scripts; `configure` shapes each new one."""

    def __init__(
        self, *scripts: Script, configure: Callable[[FakeProvider, int], None] | None = None
    ) -> None:
        self.scripts: deque[Script] = deque(scripts)
        self.created: list[FakeProvider] = []
        self._configure = configure

    def __call__(self) -> FakeProvider:
        provider = FakeProvider(self.scripts)
        if self._configure is not None:
            self._configure(provider, len(self.created))
        self.created.append(provider)
        return provider

    @property
    def last(self) -> FakeProvider:
        return self.created[-1]
