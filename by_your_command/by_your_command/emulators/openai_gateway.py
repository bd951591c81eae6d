"""OpenAI's front door, as both emulated speech APIs (Realtime, GPT-Live) answer a WebSocket upgrade:
a wrong path is HTTP 404, too many sessions 429, no key or a rejected one 401, each with the API's
JSON error body; and the server both run behind it (`GatewayServer`). What comes after the upgrade
is each API's own (openai_realtime.py and openai_session.py, gpt_live.py and gpt_live_session.py)."""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from collections.abc import Collection
from http import HTTPStatus
from typing import Protocol
from urllib.parse import urlsplit

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from by_your_command.emulators.recorded import EventRecord, LoopbackUrls, ReceivedEvent
from by_your_command.net.quiet_websockets import quiet_websocket_logger

_QUIET_WEBSOCKET_LOG = quiet_websocket_logger(__name__)


class GatewayLimits(Protocol):
    @property
    def max_connections(self) -> int: ...
    @property
    def max_frame_bytes(self) -> int: ...
    @property
    def max_recorded_bytes(self) -> int: ...  # the oldest records go first beyond this


class GatewayServer(LoopbackUrls, ABC):
    """A running emulator behind the front door: serving, stopping, the record of what clients
    sent, the open connections. An API serves one accepted connection (`_serve_connection`) at its
    path (`path_suffix`)."""

    path_suffix: str

    def __init__(self, limits: GatewayLimits, rejected_api_keys: Collection[str]) -> None:
        self.refused_handshakes = 0  # upgrades answered with an HTTP error (a client retrying shows here)
        self._max_connections, self._max_frame_bytes = limits.max_connections, limits.max_frame_bytes
        self._rejected_api_keys = rejected_api_keys
        self._record = EventRecord(limits.max_recorded_bytes)
        self._server: Server | None = None
        self._connections: set[ServerConnection] = set()
        self._next_index: int = 0  # the index the next accepted connection gets
        self.host, self.port = "", 0

    @property
    def received(self) -> list[ReceivedEvent]:
        return self._record.events()

    def received_types(self, connection: int | None = None) -> list[str]:
        return self._record.types(connection)

    @property
    def open_connections(self) -> int:
        """Client connections open right now (a closed session is gone from here)."""
        return len(self._connections)

    async def _start(self, host: str, port: int) -> None:
        self._server = await serve(
            self._serve_connection,
            host,
            port,
            max_size=self._max_frame_bytes,
            compression=None,
            process_request=self._check_handshake,
            logger=_QUIET_WEBSOCKET_LOG,
        )
        self.host, self.port = host, int(self._server.sockets[0].getsockname()[1])

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    async def serve_forever(self) -> None:
        assert self._server is not None
        await self._server.serve_forever()

    def _check_handshake(self, connection: ServerConnection, request: Request) -> Response | None:
        refused = refusal(
            connection,
            request,
            path_suffix=self.path_suffix,
            open_connections=len(self._connections),
            max_connections=self._max_connections,
            rejected_api_keys=self._rejected_api_keys,
        )
        if refused is not None:
            self.refused_handshakes += 1
        return refused

    @abstractmethod
    async def _serve_connection(self, connection: ServerConnection) -> None: ...


def refusal(
    connection: ServerConnection,
    request: Request,
    *,
    path_suffix: str,
    open_connections: int,
    max_connections: int,
    rejected_api_keys: Collection[str],
) -> Response | None:
    """The HTTP error the real gateway would answer this upgrade with, or None to accept it."""
    path = urlsplit(request.path).path
    if not path.rstrip("/").endswith(path_suffix):
        return http_error(connection, HTTPStatus.NOT_FOUND, "not_found", f"Invalid URL (GET {path})")
    if open_connections >= max_connections:
        return http_error(
            connection, HTTPStatus.TOO_MANY_REQUESTS, "rate_limit_exceeded", "Too many open sessions."
        )
    authorization = request.headers.get("Authorization", "")
    key = authorization[len("Bearer ") :].strip() if authorization.startswith("Bearer ") else ""
    if not key:
        return http_error(
            connection,
            HTTPStatus.UNAUTHORIZED,
            None,
            "You didn't provide an API key. You need to provide your API key in an Authorization header "
            "using Bearer auth (i.e. Authorization: Bearer YOUR_KEY).",
        )
    if key in rejected_api_keys:
        masked = f"{key[:3]}*****{key[-4:]}" if len(key) > 8 else "*****"
        return http_error(
            connection,
            HTTPStatus.UNAUTHORIZED,
            "invalid_api_key",
            f"Incorrect API key provided: {masked}. You can find your API key at "
            "https://platform.openai.com/account/api-keys.",
        )
    return None


def http_error(connection: ServerConnection, status: HTTPStatus, code: str | None, message: str) -> Response:
    body = {"error": {"message": message, "type": "invalid_request_error", "code": code, "param": None}}
    response = connection.respond(status, json.dumps(body) + "\n")
    del response.headers["Content-Type"]
    response.headers["Content-Type"] = "application/json"
    return response


def safe_headers(headers: Headers) -> dict[str, str]:
    """The upgrade's headers as recorded: lower-case names, never the key."""
    return {name.lower(): value for name, value in headers.raw_items() if name.lower() != "authorization"}
