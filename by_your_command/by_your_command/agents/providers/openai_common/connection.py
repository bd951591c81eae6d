"""The OpenAI SDK's WebSocket, as both speech APIs open and release it: the client (the key from the
constructor or OPENAI_API_KEY, never logged; the endpoint from config or OPENAI_BASE_URL), the
connection options, the handshake and its refusals, and the release at a session's end."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Protocol, TypeVar, cast

from openai import AsyncOpenAI, OpenAIError
from openai.types.websocket_connection_options import WebSocketConnectionOptions
from websockets.exceptions import InvalidStatus

from by_your_command.agents.events import ProviderError
from by_your_command.agents.provider import ProviderFailure
from by_your_command.agents.providers.event_stream import EventStream
from by_your_command.agents.providers.failures import handshake_refusal

MAX_SERVER_EVENT_BYTES = 16 * 1024 * 1024  # bounded memory: server events are small deltas

_Connection = TypeVar("_Connection", covariant=True)


class ConnectionManager(Protocol[_Connection]):
    """What `client.realtime.connect(...)` and `client.live.connect(...)` return."""

    async def enter(self) -> _Connection: ...


class Closable(Protocol):
    async def close(self) -> None: ...


def sdk_client(api_key: str | None, base_url: str, websocket_base_url: str) -> AsyncOpenAI:
    """The SDK client ("" for a URL: the SDK's default); no key anywhere is a fatal config error."""
    try:
        return AsyncOpenAI(
            api_key=api_key, base_url=base_url or None, websocket_base_url=websocket_base_url or None
        )
    except OpenAIError:
        raise ProviderFailure(
            ProviderError("missing_api_key", "no OpenAI API key: set OPENAI_API_KEY", fatal=True)
        ) from None


def websocket_options(quiet_logger: logging.Logger) -> WebSocketConnectionOptions:
    """Bounded frames, no compression, and a logger that never logs the handshake's headers (the key)."""
    return cast(
        WebSocketConnectionOptions,
        # `logger` is a websockets.connect option the SDK passes through but does not declare.
        {"logger": quiet_logger, "max_size": MAX_SERVER_EVENT_BYTES, "compression": None},
    )


async def open_connection(
    manager: ConnectionManager[_Connection],
    handshake_error: Callable[[int, str | None], ProviderError],
) -> _Connection:
    """The connection, or the typed refusal of its upgrade (`handshake_error`: the API's own words)."""
    try:
        return await manager.enter()
    except InvalidStatus as refused:
        response = refused.response
        raise handshake_refusal(
            handshake_error(response.status_code, response.headers.get("Retry-After"))
        ) from None


async def release(
    connection: Closable | None,
    reader: asyncio.Task[None] | None,
    events: EventStream,
    client: AsyncOpenAI | None,
) -> None:
    """A session's end: the socket closed, the reader gone (it ends `events`; with no reader they
    are ended here), the client's HTTP pool closed (unused by the WebSocket, but opened)."""
    if connection is not None:
        with contextlib.suppress(Exception):
            await connection.close()
    if reader is not None:
        reader.cancel()  # it may wait for room in a full queue nobody reads any more
        await asyncio.gather(reader, return_exceptions=True)
    else:
        events.end()
    if client is not None:
        with contextlib.suppress(Exception):
            await client.close()
