"""What both cloud providers (OpenAI Realtime, Gemini Live) make of a WebSocket that fails: the
runtime's `ProviderClosed` (retried with backoff) or `ProviderFailure` (typed: fatal or delayed)."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

from websockets.exceptions import ConnectionClosed

from by_your_command.agents.events import ProviderError
from by_your_command.agents.provider import ProviderClosed, ProviderFailure


@contextlib.asynccontextmanager
async def closing_on_failure(session: str) -> AsyncIterator[None]:
    """A connection lost while sending is `ProviderClosed` ("<session> closed: <code and reason>")."""
    try:
        yield
    except ConnectionClosed as closed:
        raise ProviderClosed(f"{session} closed: {closed}") from None


def handshake_refusal(error: ProviderError) -> ProviderFailure | ProviderClosed:
    """What to raise for a refused WebSocket upgrade: a fatal or rate-limited refusal is typed,
    anything else is a closed session the runtime retries."""
    if error.fatal or error.retry_after_s is not None:
        return ProviderFailure(error)
    return ProviderClosed(error.message)
