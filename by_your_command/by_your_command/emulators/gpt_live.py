"""A local OpenAI GPT-Live server with scripted replies: develop and test voice agents without spending.

    handle = await start(script=Script(turns=(Turn(Say("Hi there")),)))
    client = AsyncOpenAI(api_key="sk-test", base_url=handle.base_url)
    async with client.live.connect() as connection:
        await connection.session.start(session={"model": "gpt-live-1"})
        ...
    handle.received  # every client event, parsed, with the connection's index
    handle.interruptions, handle.delegations  # replies the user cut off, delegations sent
    await handle.stop()

The handshake behaves like the SDK expects: the path ends in `/live/sessions` (the model goes in
`session.start`, not the URL), `Authorization: Bearer` is required (HTTP 401 without it or for a
key in `script.rejected_api_keys`: the SDK's `connect()` raises websockets' InvalidStatus). Frames
are JSON text, validated against the SDK's types (gpt_live_wire.py); the session rules are in
gpt_live_session.py. Binds loopback by default; frames, connections and the record are bounded.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from http import HTTPStatus
from urllib.parse import urlsplit

from openai.types.live import DelegationCreatedEvent
from pydantic import BaseModel
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from by_your_command.emulators.gpt_live_script import Script
from by_your_command.emulators.gpt_live_session import GptLiveSession, ScriptCursor, SessionLimits
from by_your_command.emulators.gpt_live_wire import ClientEventError, serialise
from by_your_command.emulators.openai_wire import parse_client_frame
from by_your_command.emulators.recorded import EventRecord, LoopbackUrls, ReceivedEvent
from by_your_command.net.quiet_websockets import quiet_websocket_logger

_QUIET_WEBSOCKET_LOG = quiet_websocket_logger(__name__)

PATH_SUFFIX = "/live/sessions"


@dataclass(frozen=True)
class ServerLimits:
    max_frame_bytes: int = 16 * 1024 * 1024
    max_connections: int = 16
    max_recorded_bytes: int = 64 * 1024 * 1024  # the oldest records go first beyond this
    session: SessionLimits = field(default_factory=SessionLimits)


@dataclass(frozen=True)
class Handshake:
    connection: int
    path: str
    headers: dict[str, str]  # lower-case names; Authorization is left out (a secret)


@dataclass(frozen=True)
class Interruption:
    connection: int
    said: str  # the reply's words sent before the user talked over it


@dataclass(frozen=True)
class DelegationSent:
    connection: int
    delegation_id: str  # the id a client's commentary / thinking for it must name


class GptLiveEmulator(LoopbackUrls):
    """Handle of a running emulator (from `start`)."""

    def __init__(self, script: Script, limits: ServerLimits) -> None:
        self.script, self.limits = script, limits
        self.cursor = ScriptCursor(script)
        self.handshakes: list[Handshake] = []
        self.interruptions: list[Interruption] = []
        self.delegations: list[DelegationSent] = []  # every session.delegation.created, in order
        self.refused_handshakes = 0  # upgrades answered with an HTTP error (a client retrying shows here)
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

    @property
    def open_connections(self) -> int:
        return len(self._connections)

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

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    async def serve_forever(self) -> None:
        assert self._server is not None
        await self._server.serve_forever()

    # ---- handshake ----------------------------------------------------------------------------
    def _check_handshake(self, connection: ServerConnection, request: Request) -> Response | None:
        refusal = self._refusal(connection, request)
        if refusal is not None:
            self.refused_handshakes += 1
        return refusal

    def _refusal(self, connection: ServerConnection, request: Request) -> Response | None:
        path = urlsplit(request.path).path
        if not path.rstrip("/").endswith(PATH_SUFFIX):
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
        self.handshakes.append(Handshake(index, request.path, _safe_headers(request.headers)))
        self._connections.add(connection)

        async def send(event: BaseModel) -> None:
            if isinstance(event, DelegationCreatedEvent):
                self.delegations.append(DelegationSent(index, event.delegation.id))
            try:
                await connection.send(serialise(event))
            except ConnectionClosed:
                pass  # the client is gone; the read loop below notices and stops the session

        async def close() -> None:
            await connection.close(1000)

        def abort() -> None:
            if connection.transport is not None:
                connection.transport.abort()

        def interrupted(said: str) -> None:
            self.interruptions.append(Interruption(index, said))

        session = GptLiveSession(send, close, abort, self.cursor, self.limits.session, interrupted)
        try:
            async for frame in connection:
                try:
                    event = parse_client_frame(frame)
                except ClientEventError as error:
                    await session.refuse(error, None)
                    continue
                self._record.add(ReceivedEvent(index, event), len(frame))
                await session.handle(event)
        except ConnectionClosed:
            pass  # the client went away (or a fault dropped it): nothing to answer
        finally:
            self._connections.discard(connection)
            await session.stop()


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
) -> GptLiveEmulator:
    """Serve on host:port (0: any free port, see `.port`); stop with `await handle.stop()`."""
    emulator = GptLiveEmulator(script or Script(), limits or ServerLimits())
    await emulator._start(host, port)
    return emulator
