"""One provider session run by two supervised tasks, so the runtime never blocks on the provider.

- The writer connects (within `connect_timeout_s`), then sends queued operations one at a time,
  each within `op_timeout_s`. Operations queued while connecting wait in order: an utterance that
  starts the session streams into this queue and loses nothing.
- The reader forwards the provider's events.
Whatever ends either task (error, timeout, the server closing) is reported once as `SessionFailed`;
the runtime then closes the session. Billing runs from the start of connect to the end of close.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from by_your_command.agents.clock import Clock
from by_your_command.agents.events import ProviderError, ProviderEvent, Usage
from by_your_command.agents.provider import Provider, ProviderFailure, SessionSetup, ToolResult

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SendAudio:
    pcm: bytes


@dataclass(frozen=True)
class EndOfTurn:
    pass


@dataclass(frozen=True)
class SendText:
    text: str


@dataclass(frozen=True)
class AddContext:
    text: str


@dataclass(frozen=True)
class SendImage:
    jpeg: bytes


@dataclass(frozen=True)
class SendToolResults:
    results: tuple[ToolResult, ...]


@dataclass(frozen=True)
class SendToolProgress:
    call_id: str
    text: str


@dataclass(frozen=True)
class Interrupt:
    response_id: str
    item_id: str
    played_ms: int


@dataclass(frozen=True)
class MuteInput:
    """A full-duplex session's input muted (asleep, muted) or not: the provider's own mute."""

    muted: bool


Operation = (
    SendAudio
    | EndOfTurn
    | SendText
    | AddContext
    | SendImage
    | SendToolResults
    | SendToolProgress
    | Interrupt
    | MuteInput
)


@dataclass(frozen=True)
class SessionOpened:
    serial: int


@dataclass(frozen=True)
class SessionEvent:
    serial: int
    event: ProviderEvent


@dataclass(frozen=True)
class SessionFailed:
    serial: int
    reason: str
    connected: bool
    error: ProviderError | None = None  # a typed refusal (fatal, or rate limited)


SessionMessage = SessionOpened | SessionEvent | SessionFailed


@dataclass(frozen=True)
class SessionTimeouts:
    connect_s: float
    op_s: float
    close_s: float


# Tasks of closed sessions that outlived their close (kept referenced until they end).
_LEFT_RUNNING: set[asyncio.Task[None]] = set()


class Session:
    def __init__(
        self,
        serial: int,
        provider: Provider,
        setup: SessionSetup,
        timeouts: SessionTimeouts,
        clock: Clock,
        emit: Callable[[SessionMessage], None],
    ) -> None:
        self.serial = serial
        self.provider = provider
        self._setup = setup
        self._timeouts = timeouts
        self._clock = clock
        self._emit = emit
        self._outbox: deque[Operation] = deque()
        self._queued = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []
        self._failed = False
        self._closed = False
        self.connected = False
        self.started_at: float | None = None  # connect began (billing starts)
        self.opened_at: float | None = None
        self.usage = Usage()
        self.turns = 0

    @property
    def input_sample_rate(self) -> int:
        return self.provider.input_sample_rate

    def start(self, delay_s: float = 0.0) -> None:
        self._tasks.append(asyncio.create_task(self._write(delay_s), name=f"session {self.serial} writer"))

    def send(self, operation: Operation) -> None:
        if self._closed or self._failed:
            return  # the runtime learns of the failure through SessionFailed and replays the turn
        self._outbox.append(operation)
        self._queued.set()

    def age(self, now: float) -> float:
        return 0.0 if self.opened_at is None else now - self.opened_at

    async def close(self) -> float:
        """Stop both tasks and close the provider (within close_s); returns the billed seconds."""
        self._closed = True
        for task in self._tasks:
            task.cancel()
        await self._bounded(list(self._tasks), "its tasks")
        if self.started_at is not None:
            closing = asyncio.create_task(self.provider.close(), name=f"session {self.serial} close")
            await self._bounded([closing], "the provider's close")
            if closing.done() and not closing.cancelled() and closing.exception() is not None:
                # a close that fails still ends our billing view
                log.warning("session %d: provider close failed: %r", self.serial, closing.exception())
        if self.opened_at is None or self.started_at is None:
            return 0.0  # never connected: nothing billed
        return self._clock.now() - self.started_at

    async def _bounded(self, tasks: list[asyncio.Task[None]], what: str) -> None:
        """Wait at most close_s for `tasks`, never longer: a task that ignores its cancellation (a
        library's close handshake) must not hold the scheduler. One still running is cancelled,
        kept referenced until it ends, and logged."""
        if not tasks:
            return
        _, pending = await asyncio.wait(tasks, timeout=self._timeouts.close_s)
        for task in tasks:
            if task.done() and not task.cancelled():
                task.exception()  # retrieved: reported by the caller or not at all, never "never retrieved"
        for task in pending:
            task.cancel()
            _LEFT_RUNNING.add(task)
            task.add_done_callback(_LEFT_RUNNING.discard)
        if pending:
            log.warning(
                "session %d: %s did not end within %.1f s; left to finish on its own",
                self.serial,
                what,
                self._timeouts.close_s,
            )

    # --- tasks -------------------------------------------------------------------------------

    def _fail(self, reason: str, error: ProviderError | None = None) -> None:
        if not (self._failed or self._closed):
            self._failed = True
            self._emit(SessionFailed(self.serial, reason, self.connected, error))

    async def _write(self, delay_s: float) -> None:
        try:
            if delay_s > 0:
                await self._clock.sleep(delay_s)
            self.started_at = self._clock.now()
            await asyncio.wait_for(self.provider.connect(self._setup), self._timeouts.connect_s)
            self.connected = True
            self.opened_at = self._clock.now()
            self._tasks.append(asyncio.create_task(self._read(), name=f"session {self.serial} reader"))
            self._emit(SessionOpened(self.serial))
            while True:
                while not self._outbox:
                    self._queued.clear()
                    await self._queued.wait()
                operation = self._outbox[0]
                await asyncio.wait_for(self._perform(operation), self._timeouts.op_s)
                self._outbox.popleft()
        except asyncio.CancelledError:
            raise
        except ProviderFailure as failure:
            self._fail(str(failure), failure.error)
        except asyncio.TimeoutError:
            stage = "sending" if self.connected else "connecting"
            self._fail(f"provider did not answer while {stage} (deadline)")
        except Exception as error:  # any failure ends this session, reported once
            self._fail(f"provider failed: {error!r}")

    async def _perform(self, operation: Operation) -> None:
        provider = self.provider
        if isinstance(operation, SendAudio):
            await provider.send_audio(operation.pcm)
        elif isinstance(operation, EndOfTurn):
            await provider.end_of_turn()
        elif isinstance(operation, SendText):
            await provider.send_text(operation.text)
        elif isinstance(operation, AddContext):
            await provider.add_context(operation.text)
        elif isinstance(operation, SendImage):
            await provider.send_image(operation.jpeg)
        elif isinstance(operation, SendToolResults):
            await provider.send_tool_results(operation.results)
        elif isinstance(operation, SendToolProgress):
            await provider.send_tool_progress(operation.call_id, operation.text)
        elif isinstance(operation, MuteInput):
            mute = getattr(provider, "mute" if operation.muted else "unmute", None)
            if mute is not None:  # only full-duplex providers have an input to mute
                await mute()
        else:
            await provider.interrupt(operation.response_id, operation.item_id, operation.played_ms)

    async def _read(self) -> None:
        try:
            async for event in self.provider.events():
                self._emit(SessionEvent(self.serial, event))
            self._fail("the provider closed the session")
        except asyncio.CancelledError:
            raise
        except ProviderFailure as failure:
            self._fail(str(failure), failure.error)
        except Exception as error:  # reported once, then the runtime recycles
            self._fail(f"provider event stream failed: {error!r}")
