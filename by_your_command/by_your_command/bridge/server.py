"""The WebSocket side of the bridge: accept (or refuse) connections and pump frames for BridgeCore."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from http import HTTPStatus

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from by_your_command.bridge.auth import check_bind, presented_token, token_matches
from by_your_command.bridge.core import BridgeCore, ClientSession

log = logging.getLogger(__name__)

# Frames above the protocol limit get a status error; far larger ones close the connection (1009)
# so a client cannot make us buffer arbitrary amounts before we can say no.
HARD_LIMIT_FACTOR = 4


class BridgeServer:
    def __init__(self, core: BridgeCore, token: str) -> None:
        self.core = core
        self._token = token
        self._server: Server | None = None
        self.refused_connections = 0

    @property
    def port(self) -> int:
        if self._server is None:
            raise RuntimeError("server not started")
        return int(self._server.sockets[0].getsockname()[1])

    async def start(self) -> None:
        params = self.core.params
        check_bind(params.host, self._token)
        self._server = await serve(
            self._handle,
            params.host,
            params.port,
            compression=None,  # deflate costs 5-40x on audio/image frames (DESIGN.md §11)
            max_size=params.max_message_bytes * HARD_LIMIT_FACTOR,
            process_request=self._admit,
            ping_interval=params.ping_interval_s or None,
            close_timeout=2,  # a client that stopped reading must not hold up shutdown for long
        )
        log.info(
            "bridge listening on %s:%d (token %s)",
            params.host,
            self.port,
            "required" if self._token else "not required",
        )

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    def _admit(self, connection: ServerConnection, request: Request) -> Response | None:
        """Runs before the handshake completes: wrong token or too many clients → HTTP refusal."""
        presented = presented_token(request.headers.get("Authorization"), request.path)
        peer = _peer(connection)
        if not token_matches(self._token, presented):
            self.refused_connections += 1
            log.warning("refused %s: %s token", peer, "missing" if presented is None else "wrong")
            return _refusal(HTTPStatus.UNAUTHORIZED, "a valid bridge token is required\n")
        if len(self.core.sessions) >= self.core.params.max_clients:
            self.refused_connections += 1
            log.warning("refused %s: already %d clients", peer, self.core.params.max_clients)
            return _refusal(HTTPStatus.SERVICE_UNAVAILABLE, "too many bridge clients\n")
        return None

    async def _handle(self, connection: ServerConnection) -> None:
        session = self.core.open_session(_peer(connection))
        sender = asyncio.create_task(self._send_loop(connection, session))
        try:
            async for frame in connection:
                self.core.handle_frame(session, frame)
        except ConnectionClosed:
            pass
        finally:
            self.core.close_session(session)
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sender

    async def _send_loop(self, connection: ServerConnection, session: ClientSession) -> None:
        try:
            while True:
                text = await session.queue.get()
                await connection.send(text)  # waits while the socket's buffer is full: backpressure
                session.sent_messages += 1
                session.sent_bytes += len(text)
        except ConnectionClosed:
            pass


def _peer(connection: ServerConnection) -> str:
    address = connection.remote_address
    return f"{address[0]}:{address[1]}" if address else "?"


def _refusal(status: HTTPStatus, body: str) -> Response:
    headers = Headers([("Content-Type", "text/plain"), ("Content-Length", str(len(body)))])
    return Response(status.value, status.phrase, headers, body.encode())
