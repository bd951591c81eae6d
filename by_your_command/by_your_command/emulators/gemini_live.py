"""A local Gemini Live (BidiGenerateContent) server with scripted replies, over TLS by default.

    emulator = await start(script=Script(turns=(Turn(Say("Hi there")),)))
    client = genai.Client(api_key="test-key", http_options=types.HttpOptions(
        base_url=emulator.base_url, api_version="v1beta",
        async_client_args={"ssl": emulator.client_ssl_context()}))
    ...
    emulator.received   # every client message, parsed, with its connection's index
    await emulator.stop()

google-genai turns every base URL into `wss://` for API-key clients, so the emulator serves TLS with
a self-signed certificate made at start (`cert_file`; `tls=False` serves plain `ws://` for raw
clients). The handshake accepts any `*.GenerativeService.BidiGenerateContent` path and the key as
`x-goog-api-key` header or `?key=`. Like the real server, refusals are close frames after the setup
message: no key → 1008, a rejected key → 1007 "API key not valid", an unknown model → 1008, a bad
frame → 1007, a refused resumption handle → 1007, the deadline → 1011. Binds loopback by default;
frames, connections, the record and the handle store are bounded. Session rules: gemini_session.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import secrets
import shutil
import ssl
import tempfile
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from http import HTTPStatus
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response
from websockets.protocol import State

from by_your_command.emulators.gemini_script import Script
from by_your_command.emulators.gemini_session import (
    Conversation,
    GeminiLiveSession,
    ScriptCursor,
    SessionConfig,
    SessionLimits,
)
from by_your_command.emulators.gemini_tls import TlsFiles, client_context, make_self_signed, server_context
from by_your_command.emulators.gemini_wire import (
    CLOSE_INVALID_ARGUMENT,
    CLOSE_POLICY,
    INVALID_ARGUMENT,
    JsonObject,
    WireError,
    close_reason,
    parse_client_frame,
)
from by_your_command.net.quiet_websockets import quiet_websocket_logger

_QUIET_WEBSOCKET_LOG = quiet_websocket_logger(__name__)

METHOD_SUFFIX = ".GenerativeService.BidiGenerateContent"
NO_KEY = (
    "Method doesn't allow unregistered callers (callers without established identity). "
    "Please use API Key or other form of API consumer identity to call this API."
)
BAD_KEY = "API key not valid. Please pass a valid API key."


@dataclass(frozen=True)
class ServerLimits:
    max_frame_bytes: int = 16 * 1024 * 1024
    max_connections: int = 16
    max_recorded_bytes: int = 64 * 1024 * 1024  # the oldest records go first beyond this
    max_handles: int = 1024  # the oldest resumption handles are forgotten beyond this
    setup_timeout_s: float = 30.0  # a client that never sends its setup is closed
    session: SessionLimits = field(default_factory=SessionLimits)


@dataclass(frozen=True)
class ReceivedMessage:
    connection: int  # 0 for the first connection this emulator accepted, and so on
    kind: str  # setup | clientContent | realtimeInput | toolResponse (camelCase, whatever was sent)
    body: JsonObject


@dataclass(frozen=True)
class Handshake:
    connection: int
    path: str  # without the query (it may hold the key)
    api_version: str  # from the path, e.g. v1beta
    key_source: str  # "header", "query" or "" (none)
    headers: dict[str, str]  # lower-case names; x-goog-api-key and authorization left out


@dataclass(frozen=True)
class Closed:
    connection: int
    code: int
    reason: str


class _Record:
    """What clients sent, bounded by the size of the frames it keeps."""

    def __init__(self, max_bytes: int) -> None:
        self._items: deque[tuple[ReceivedMessage, int]] = deque()
        self._bytes, self._max_bytes = 0, max_bytes

    def add(self, message: ReceivedMessage, size: int) -> None:
        self._items.append((message, size))
        self._bytes += size
        while self._bytes > self._max_bytes and len(self._items) > 1:
            self._bytes -= self._items.popleft()[1]

    def messages(self) -> list[ReceivedMessage]:
        return [message for message, _ in self._items]


@dataclass
class _Handle:
    conversation: Conversation
    issued_at: float
    origin_open: Callable[[], bool]


class HandleStore:
    """Resumption handles: each names a snapshot of a conversation; valid for `ttl_s` after issue
    and only once the connection that issued it is closed (a resume is refused while the old
    socket is still open: aicc2025/sip-to-ai#14)."""

    def __init__(self, ttl_s: float, max_handles: int, clock: Callable[[], float]) -> None:
        self._handles: OrderedDict[str, _Handle] = OrderedDict()
        self._ttl_s, self._max, self._clock = ttl_s, max_handles, clock

    def issue(self, conversation: Conversation, origin_open: Callable[[], bool]) -> str:
        handle = "emu-handle-" + secrets.token_urlsafe(12)
        self._handles[handle] = _Handle(conversation, self._clock(), origin_open)
        while len(self._handles) > self._max:
            self._handles.popitem(last=False)
        return handle

    @property
    def issued(self) -> list[str]:
        """The handles still kept, oldest first (tests check which one a client resumed with)."""
        return list(self._handles)

    def claim(self, handle: str) -> Conversation:
        entry = self._handles.get(handle)
        if entry is None or self._clock() - entry.issued_at > self._ttl_s:
            raise WireError(f"{INVALID_ARGUMENT} The session resumption handle is invalid or expired.")
        if entry.origin_open():
            raise WireError(f"{INVALID_ARGUMENT} The session to resume is still connected.")
        return entry.conversation.copy()


class GeminiLiveEmulator:
    """Handle of a running emulator (from `start`)."""

    def __init__(self, script: Script, limits: ServerLimits, clock: Callable[[], float]) -> None:
        self.script, self.limits = script, limits
        self.cursor = ScriptCursor(script)
        self.handles = HandleStore(script.handle_ttl_s, limits.max_handles, clock)
        self.handshakes: list[Handshake] = []
        self.closes: list[Closed] = []  # close frames the emulator sent, in order
        self.sessions: dict[int, GeminiLiveSession] = {}  # by connection index (set up ones)
        self._record = _Record(limits.max_recorded_bytes)
        self._server: Server | None = None
        self._connections: set[ServerConnection] = set()
        self._closing: set[asyncio.Future[None]] = set()
        self._indexes = itertools.count()
        self._tls: TlsFiles | None = None
        self._tls_dir: Path | None = None
        self.host, self.port = "", 0

    # ---- what tests and tools read ----------------------------------------------------------
    @property
    def received(self) -> list[ReceivedMessage]:
        return self._record.messages()

    def received_of(self, kind: str, connection: int | None = None) -> list[JsonObject]:
        return [
            record.body
            for record in self.received
            if record.kind == kind and (connection is None or record.connection == connection)
        ]

    @property
    def cert_file(self) -> Path | None:
        """The self-signed certificate (PEM) a client must trust; None when serving plain ws://."""
        return self._tls.cert_file if self._tls else None

    def client_ssl_context(self) -> ssl.SSLContext:
        if self._tls is None:
            raise RuntimeError("this emulator serves plain ws://: no TLS to trust")
        return client_context(self._tls.cert_file)

    @property
    def base_url(self) -> str:
        """For `HttpOptions(base_url=...)` or GOOGLE_GEMINI_BASE_URL (the SDK makes it wss://)."""
        scheme = "https" if self._tls else "http"
        return f"{scheme}://{self._url_host}:{self.port}"

    @property
    def websocket_url(self) -> str:
        """The full endpoint, for raw WebSocket clients (v1beta)."""
        scheme = "wss" if self._tls else "ws"
        return (
            f"{scheme}://{self._url_host}:{self.port}/ws/google.ai.generativelanguage.v1beta{METHOD_SUFFIX}"
        )

    @property
    def _url_host(self) -> str:
        return f"[{self.host}]" if ":" in self.host else self.host

    # ---- lifecycle --------------------------------------------------------------------------
    async def _start(self, host: str, port: int, tls: bool) -> None:
        context = None
        if tls:
            self._tls_dir = Path(tempfile.mkdtemp(prefix="byc-gemini-emulator-"))
            self._tls = make_self_signed(self._tls_dir, host)
            context = server_context(self._tls)
        self._server = await serve(
            self._serve_connection,
            host,
            port,
            ssl=context,
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
        if self._tls_dir is not None:
            shutil.rmtree(self._tls_dir, ignore_errors=True)

    async def serve_forever(self) -> None:
        assert self._server is not None
        await self._server.serve_forever()

    # ---- handshake --------------------------------------------------------------------------
    def _check_handshake(self, connection: ServerConnection, request: Request) -> Response | None:
        path = urlsplit(request.path).path
        if not path.endswith(METHOD_SUFFIX):
            return connection.respond(HTTPStatus.NOT_FOUND, f"no method at {path}\n")
        if len(self._connections) >= self.limits.max_connections:
            return connection.respond(HTTPStatus.TOO_MANY_REQUESTS, "too many open sessions\n")
        return None

    # ---- one connection ---------------------------------------------------------------------
    async def _serve_connection(self, connection: ServerConnection) -> None:
        index = next(self._indexes)
        request = connection.request
        assert request is not None
        parts = urlsplit(request.path)
        header_key = request.headers.get("x-goog-api-key", "")
        query_key = (parse_qs(parts.query).get("key") or [""])[0]
        version = parts.path.rsplit("/", 1)[-1].split(".")[-3] if parts.path.count(".") >= 3 else ""
        self.handshakes.append(
            Handshake(
                index,
                parts.path,
                version,
                "header" if header_key else "query" if query_key else "",
                {
                    name.lower(): value
                    for name, value in request.headers.raw_items()
                    if name.lower() not in ("x-goog-api-key", "authorization")
                },
            )
        )
        self._connections.add(connection)
        session: GeminiLiveSession | None = None
        try:
            session = await self._set_up(connection, index, header_key or query_key)
            if session is None:
                return
            async for frame in connection:
                kind, body = parse_client_frame(frame)
                self._record.add(ReceivedMessage(index, kind, body), len(frame))
                await session.handle(kind, body)
        except WireError as error:
            await self._close(connection, index, error.code, error.reason)
        except ConnectionClosed:
            pass  # the client went away (or a fault dropped it)
        finally:
            self._connections.discard(connection)
            if session is not None:
                await session.stop()

    async def _set_up(self, connection: ServerConnection, index: int, key: str) -> GeminiLiveSession | None:
        """Read and check the setup; send setupComplete. None when the connection was refused."""
        try:
            frame = await asyncio.wait_for(connection.recv(), self.limits.setup_timeout_s)
        except asyncio.TimeoutError:
            await self._close(connection, index, CLOSE_INVALID_ARGUMENT, "No setup message received in time.")
            return None
        kind, body = parse_client_frame(frame)
        self._record.add(ReceivedMessage(index, kind, body), len(frame))
        if not key:
            await self._close(connection, index, CLOSE_POLICY, NO_KEY)
            return None
        if key in self.script.rejected_api_keys:
            await self._close(connection, index, CLOSE_INVALID_ARGUMENT, BAD_KEY)
            return None
        if kind != "setup":
            raise WireError(f"{INVALID_ARGUMENT} The first message must be setup.")
        config = SessionConfig.from_setup(body)
        if self.script.known_models and config.model not in self.script.known_models:
            version = self.handshakes[-1].api_version if self.handshakes else "v1beta"
            await self._close(
                connection,
                index,
                CLOSE_POLICY,
                f"models/{config.model} is not found for API version {version}, "
                "or is not supported for bidiGenerateContent.",
            )
            return None
        conversation = Conversation()
        if config.resume_handle:
            if self.script.refuse_resume:
                raise WireError(f"{INVALID_ARGUMENT} The session cannot be resumed.")
            conversation = self.handles.claim(config.resume_handle)

        def is_open() -> bool:
            return connection.state is State.OPEN

        async def send(message: JsonObject) -> None:
            await connection.send(_json(message))

        async def close(code: int, reason: str) -> None:
            # Not awaited in the caller's task: closing cancels that very task (the reply).
            closing = asyncio.ensure_future(self._close(connection, index, code, reason))
            self._closing.add(closing)
            closing.add_done_callback(self._closing.discard)

        def abort() -> None:
            if connection.transport is not None:
                connection.transport.abort()

        session = GeminiLiveSession(
            config,
            conversation,
            self.cursor,
            send,
            close,
            abort,
            lambda snapshot: self.handles.issue(snapshot, is_open),
            self.limits.session,
        )
        await connection.send(_json({"setupComplete": {}}))
        self.sessions[index] = session
        await session.start()
        return session

    async def _close(self, connection: ServerConnection, index: int, code: int, reason: str) -> None:
        if connection.state is not State.OPEN:
            return
        reason = close_reason(reason)
        self.closes.append(Closed(index, code, reason))
        with contextlib.suppress(ConnectionClosed):
            await connection.close(code, reason)


def _json(message: JsonObject) -> str:
    return json.dumps(message, separators=(",", ":"))


async def start(
    host: str = "127.0.0.1",
    port: int = 0,
    script: Script | None = None,
    limits: ServerLimits | None = None,
    tls: bool = True,
    clock: Callable[[], float] = time.monotonic,
) -> GeminiLiveEmulator:
    """Serve on host:port (0: any free port, see `.port`); stop with `await emulator.stop()`.
    `clock` times resumption handles (tests pass their own to expire them)."""
    emulator = GeminiLiveEmulator(script or Script(), limits or ServerLimits(), clock)
    await emulator._start(host, port, tls)
    return emulator
