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

from dataclasses import dataclass, field

from openai.types.live import DelegationCreatedEvent
from pydantic import BaseModel
from websockets.asyncio.server import ServerConnection
from websockets.exceptions import ConnectionClosed

from by_your_command.emulators.gpt_live_script import Script
from by_your_command.emulators.gpt_live_session import GptLiveSession, ScriptCursor, SessionLimits
from by_your_command.emulators.gpt_live_wire import ClientEventError, serialise
from by_your_command.emulators.openai_gateway import GatewayServer, safe_headers
from by_your_command.emulators.openai_wire import parse_client_frame
from by_your_command.emulators.recorded import ReceivedEvent

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


class GptLiveEmulator(GatewayServer):
    """Handle of a running emulator (from `start`)."""

    path_suffix = PATH_SUFFIX

    def __init__(self, script: Script, limits: ServerLimits) -> None:
        super().__init__(limits, script.rejected_api_keys)
        self.script, self.limits = script, limits
        self.cursor = ScriptCursor(script)
        self.handshakes: list[Handshake] = []
        self.interruptions: list[Interruption] = []
        self.delegations: list[DelegationSent] = []  # every session.delegation.created, in order

    # ---- one connection -----------------------------------------------------------------------
    async def _serve_connection(self, connection: ServerConnection) -> None:
        index, self._next_index = self._next_index, self._next_index + 1
        request = connection.request
        assert request is not None
        self.handshakes.append(Handshake(index, request.path, safe_headers(request.headers)))
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


async def start(
    host: str = "127.0.0.1", port: int = 0, script: Script | None = None, limits: ServerLimits | None = None
) -> GptLiveEmulator:
    """Serve on host:port (0: any free port, see `.port`); stop with `await handle.stop()`."""
    emulator = GptLiveEmulator(script or Script(), limits or ServerLimits())
    await emulator._start(host, port)
    return emulator
