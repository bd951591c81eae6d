"""Every TCP connection the server accepted, from accept on, so a stop can end the ones that never opened.

websockets lists a connection only once its WebSocket handshake completed, and on `close()` waits
for the others until their `open_timeout`. Browsers open idle TCP connections ahead of use (no
request ever comes on them): with the monitor page open, every stop waited out that timeout.
"""

from __future__ import annotations

import asyncio

from websockets.asyncio.server import ServerConnection
from websockets.protocol import CONNECTING


def tracked_connection_class(registry: set[ServerConnection]) -> type[ServerConnection]:
    """A ServerConnection that is in `registry` from TCP accept until the connection is lost."""

    class TrackedConnection(ServerConnection):
        def connection_made(self, transport: asyncio.BaseTransport) -> None:
            super().connection_made(transport)
            registry.add(self)

        def connection_lost(self, exc: Exception | None) -> None:
            registry.discard(self)
            super().connection_lost(exc)

    return TrackedConnection


def abort_unopened(registry: set[ServerConnection]) -> int:
    """Drop the connections still before or inside their opening handshake; returns how many.

    They asked for nothing yet (or not all of it), so there is nobody to say goodbye to."""
    unopened = [connection for connection in registry if connection.protocol.state is CONNECTING]
    for connection in unopened:
        connection.transport.abort()
    return len(unopened)
