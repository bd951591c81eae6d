"""A local OpenAI Realtime (GA) server with scripted replies: develop and test agents without spending.

    handle = await start(script=Script(turns=(Turn(Say("Hi there")),)))
    client = AsyncOpenAI(api_key="sk-test", websocket_base_url=handle.websocket_base_url)
    ...
    handle.received  # every client event, parsed, with the connection's index
    await handle.stop()

The handshake behaves like the real one: the path ends in `/realtime`, `Authorization: Bearer`
is required (HTTP 401 without it or for a key in `script.rejected_api_keys`), and the legacy beta
header gets the real server's `beta_api_shape_disabled` error and close code 4000. The session
rules are in openai_session.py. Binds loopback by default; every frame is validated, frames,
buffers, connections and the record are bounded.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from dataclasses import dataclass, field
from http import HTTPStatus
from typing import Any
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from by_your_command.emulators.openai_script import Script
from by_your_command.emulators.openai_session import OpenAIRealtimeSession, ScriptCursor, SessionLimits
from by_your_command.emulators.openai_wire import (
    ClientEventError,
    JsonObject,
    error_event,
    parse_client_frame,
)
from by_your_command.emulators.recorded import EventRecord, LoopbackUrls, ReceivedEvent
from by_your_command.net.quiet_websockets import quiet_websocket_logger

_QUIET_WEBSOCKET_LOG = quiet_websocket_logger(__name__)

DEFAULT_MODEL = "gpt-realtime-2.1"
BETA_CLOSE_CODE = 4000


@dataclass(frozen=True)
class ServerLimits:
    max_frame_bytes: int = 16 * 1024 * 1024  # the API takes appends up to 15 MiB
    max_connections: int = 16
    max_recorded_bytes: int = 64 * 1024 * 1024  # the oldest records go first beyond this
    session: SessionLimits = field(default_factory=SessionLimits)


@dataclass(frozen=True)
class Handshake:
    connection: int
    path: str
    model: str
    headers: dict[str, str]  # lower-case names; Authorization is left out (a secret)


class OpenAIRealtimeEmulator(LoopbackUrls):
    """Handle of a running emulator (from `start`)."""

    def __init__(self, script: Script, limits: ServerLimits) -> None:
        self.script, self.limits = script, limits
        self.cursor = ScriptCursor(script)
        self.handshakes: list[Handshake] = []
        self._record = EventRecord(limits.max_recorded_bytes)
        self._server: Server | None = None
        self._connections: set[ServerConnection] = set()
        self._next_index = 0
        self.host, self.port = "", 0

    @property
    def received(self) -> list[ReceivedEvent]:
        return self._record.events()

    def received_types(self, connection: int | None = None) -> list[str]:
        return self._record.types(connection)

    async def _start(self, host: str, port: int) -> None:
        self._server = await serve(
            self._serve_connection,
            host,
            port,
            max_size=self.limits.max_frame_bytes,
            compression=None,
            process_request=self._check_handshake,
            logger=_QUIET_WEBSOCKET_LOG,
        )
        self.host, self.port = host, int(self._server.sockets[0].getsockname()[1])

    @property
    def open_connections(self) -> int:
        """Client connections open right now (a closed session is gone from here)."""
        return len(self._connections)

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    async def serve_forever(self) -> None:
        assert self._server is not None
        await self._server.serve_forever()

    # ---- handshake ----------------------------------------------------------------------------
    def _check_handshake(self, connection: ServerConnection, request: Request) -> Response | None:
        path = urlsplit(request.path).path
        if not path.rstrip("/").endswith("/realtime"):
            return _http_error(connection, HTTPStatus.NOT_FOUND, "not_found", f"Invalid URL (GET {path})")
        if len(self._connections) >= self.limits.max_connections:
            return _http_error(
                connection, HTTPStatus.TOO_MANY_REQUESTS, "rate_limit_exceeded", "Too many open sessions."
            )
        authorization = request.headers.get("Authorization", "")
        key = authorization[len("Bearer ") :].strip() if authorization.startswith("Bearer ") else ""
        if not key:
            return _http_error(
                connection,
                HTTPStatus.UNAUTHORIZED,
                None,
                "You didn't provide an API key. You need to provide your API key in an Authorization header "
                "using Bearer auth (i.e. Authorization: Bearer YOUR_KEY).",
            )
        if key in self.script.rejected_api_keys:
            masked = f"{key[:3]}*****{key[-4:]}" if len(key) > 8 else "*****"
            return _http_error(
                connection,
                HTTPStatus.UNAUTHORIZED,
                "invalid_api_key",
                f"Incorrect API key provided: {masked}. You can find your API key at "
                "https://platform.openai.com/account/api-keys.",
            )
        return None

    # ---- one connection -----------------------------------------------------------------------
    async def _serve_connection(self, connection: ServerConnection) -> None:
        index, self._next_index = self._next_index, self._next_index + 1
        request = connection.request
        assert request is not None
        model = (parse_qs(urlsplit(request.path).query).get("model") or [DEFAULT_MODEL])[0]
        self.handshakes.append(Handshake(index, request.path, model, _safe_headers(request.headers)))
        self._connections.add(connection)
        try:
            if "realtime=v1" in request.headers.get("OpenAI-Beta", ""):
                await _send(
                    connection,
                    error_event(
                        "beta_api_shape_disabled",
                        "The Realtime Beta API is no longer supported. "
                        "Please use /v1/realtime for the GA API.",
                    ),
                )
                await connection.close(BETA_CLOSE_CODE, "invalid_request_error.beta_api_shape_disabled")
                return
            await self._converse(connection, index, model)
        finally:
            self._connections.discard(connection)

    async def _converse(self, connection: ServerConnection, index: int, model: str) -> None:
        def abort() -> None:
            if connection.transport is not None:
                connection.transport.abort()

        async def send(event: JsonObject) -> None:
            await _send(connection, event)

        session = OpenAIRealtimeSession(send, abort, self.cursor, model, self.limits.session)
        expiry = (
            asyncio.ensure_future(self._expire(connection, session, self.script.session_expiry_s))
            if self.script.session_expiry_s is not None
            else None
        )
        try:
            await session.start()
            async for frame in connection:
                try:
                    event = parse_client_frame(frame)
                except ClientEventError as error:
                    await send(error_event(error.code, error.message, error.param))
                    continue
                self._record.add(ReceivedEvent(index, event), len(frame))
                await session.handle(event)
        except ConnectionClosed:
            pass  # the client went away (or a fault dropped it): nothing to answer
        finally:
            if expiry is not None:
                expiry.cancel()
            await session.close()

    @staticmethod
    async def _expire(connection: ServerConnection, session: OpenAIRealtimeSession, after_s: float) -> None:
        await asyncio.sleep(after_s)
        minutes = after_s / 60
        with contextlib.suppress(ConnectionClosed):
            await session.send(
                "error",
                error={
                    "type": "invalid_request_error",
                    "code": "session_expired",
                    "message": f"Your session hit the maximum duration of {minutes:g} minutes.",
                    "param": None,
                    "event_id": None,
                },
            )
            await connection.close(1000, "session expired")


async def _send(connection: ServerConnection, event: dict[str, Any]) -> None:
    await connection.send(json.dumps(event))


def _http_error(connection: ServerConnection, status: HTTPStatus, code: str | None, message: str) -> Response:
    body = {"error": {"message": message, "type": "invalid_request_error", "code": code, "param": None}}
    response = connection.respond(status, json.dumps(body) + "\n")
    del response.headers["Content-Type"]
    response.headers["Content-Type"] = "application/json"
    return response


def _safe_headers(headers: Headers) -> dict[str, str]:
    return {name.lower(): value for name, value in headers.raw_items() if name.lower() != "authorization"}


async def start(
    host: str = "127.0.0.1", port: int = 0, script: Script | None = None, limits: ServerLimits | None = None
) -> OpenAIRealtimeEmulator:
    """Serve on host:port (0: any free port, see `.port`); stop with `await handle.stop()`."""
    emulator = OpenAIRealtimeEmulator(script or Script(), limits or ServerLimits())
    await emulator._start(host, port)
    return emulator
