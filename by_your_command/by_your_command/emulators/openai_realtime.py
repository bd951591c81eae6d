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
from typing import Any
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed

from by_your_command.emulators.openai_gateway import GatewayServer, safe_headers
from by_your_command.emulators.openai_script import Script
from by_your_command.emulators.openai_session import OpenAIRealtimeSession, ScriptCursor, SessionLimits
from by_your_command.emulators.openai_wire import (
    ClientEventError,
    JsonObject,
    error_event,
    parse_client_frame,
)
from by_your_command.emulators.recorded import ReceivedEvent

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


class OpenAIRealtimeEmulator(GatewayServer):
    """Handle of a running emulator (from `start`)."""

    path_suffix = "/realtime"

    def __init__(self, script: Script, limits: ServerLimits) -> None:
        super().__init__(limits, script.rejected_api_keys)
        self.script, self.limits = script, limits
        self.cursor = ScriptCursor(script)
        self.handshakes: list[Handshake] = []

    # ---- one connection -----------------------------------------------------------------------
    async def _serve_connection(self, connection: ServerConnection) -> None:
        index, self._next_index = self._next_index, self._next_index + 1
        request = connection.request
        assert request is not None
        model = (parse_qs(urlsplit(request.path).query).get("model") or [DEFAULT_MODEL])[0]
        self.handshakes.append(Handshake(index, request.path, model, safe_headers(request.headers)))
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


async def start(
    host: str = "127.0.0.1", port: int = 0, script: Script | None = None, limits: ServerLimits | None = None
) -> OpenAIRealtimeEmulator:
    """Serve on host:port (0: any free port, see `.port`); stop with `await handle.stop()`."""
    emulator = OpenAIRealtimeEmulator(script or Script(), limits or ServerLimits())
    await emulator._start(host, port)
    return emulator
