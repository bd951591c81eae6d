"""The contract between the agent runtime and one vendor's realtime session.

One `Provider` object is one session: `connect` opens it, `close` ends it, and a closed provider is
never reused (the runtime builds a new one through a `ProviderFactory`). Every method may raise
`ProviderClosed` once the session is gone; a method never blocks longer than the deadline the
runtime gives it (it wraps calls in timeouts), so implementations need not add their own.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Protocol

from by_your_command.agents.events import ProviderError, ProviderEvent


class Role(str, Enum):
    USER = "user"
    ASSISTANT = "assistant"


@dataclass(frozen=True)
class HistoryTurn:
    """One turn carried into a new session as text context (audio is never replayed)."""

    role: Role
    text: str


@dataclass(frozen=True)
class ToolSpec:
    name: str
    description: str
    parameters: dict[str, object]  # JSON schema
    # A robot action that runs on after the call (docs/tools.md): its result comes later, with
    # progress on the way; the model keeps talking meanwhile (Gemini: NON_BLOCKING).
    long_running: bool = False
    # What a user says to call it without a model (the offline provider): (phrase, arguments JSON).
    spoken: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class ToolResult:
    call_id: str
    output: str  # JSON


@dataclass(frozen=True)
class SessionSetup:
    instructions: str
    history: Sequence[HistoryTurn] = ()
    tools: Sequence[ToolSpec] = ()
    audio_out: bool = True  # False: text replies only (command agents)
    # The runtime's conversation: a provider may continue server-side state (Gemini resumption)
    # only into a session of the same conversation; a reset starts a new one.
    conversation_id: str = ""


class ProviderClosed(ConnectionError):
    """The session is closed (by us, by the server, or by a network failure)."""


class ProviderFailure(Exception):
    """`connect` (or any call) was refused with a typed error: `error.fatal` (bad key, unknown model)
    stops the agent; `error.retry_after_s` (rate limit) delays the next attempt. Other exceptions
    (OSError, TimeoutError, ProviderClosed) are retried with backoff."""

    def __init__(self, error: ProviderError) -> None:
        super().__init__(f"{error.code}: {error.message}")
        self.error = error


class Provider(Protocol):
    name: str
    input_sample_rate: int  # the rate send_audio expects; the runtime resamples to it
    max_session_s: float  # the provider's own session limit; the runtime rotates before it

    async def connect(self, setup: SessionSetup) -> None: ...

    async def send_audio(self, pcm: bytes) -> None:
        """Append user audio (mono int16 LE at input_sample_rate) to the current user turn."""

    async def end_of_turn(self) -> None:
        """The user stopped speaking: commit the turn and ask for a reply."""

    async def send_text(self, text: str) -> None:
        """A typed user turn that gets a reply."""

    async def add_context(self, text: str) -> None:
        """Something the model must know from now on (the robot was stopped): a user-side note in
        its history, no reply asked for."""

    async def send_image(self, jpeg: bytes) -> None:
        """A camera frame for the model to look at with the next turn."""

    async def send_tool_results(self, results: Sequence[ToolResult]) -> None:
        """The results of every ToolCall of one response, together: the model continues with one
        reply (the runtime never sends part of a response's results)."""

    async def send_tool_progress(self, call_id: str, text: str) -> None:
        """How a long-running call (a robot action) is going: the model knows it from now on, no
        reply is asked for, the call stays open (its result comes with send_tool_results)."""

    async def interrupt(self, response_id: str, item_id: str, played_ms: int) -> None:
        """Cancel the reply and make the history match what was heard: `played_ms` of `item_id`
        (clamped by the provider to the audio it actually produced)."""

    async def close(self) -> None: ...

    def events(self) -> AsyncIterator[ProviderEvent]:
        """Events of this session, in the order the server sent them; ends when it closes."""


class ProviderFactory(Protocol):
    def __call__(self) -> Provider: ...
