"""The WebSocket side of the bridge: accept (or refuse) connections and pump frames for BridgeCore."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from http import HTTPStatus

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

from by_your_command.bridge.auth import check_bind, is_loopback, presented_token, token_matches
from by_your_command.bridge.core import BridgeCore, ClientSession
from by_your_command.bridge.flow import LogLimiter
from by_your_command.bridge.protocol import preview, utf8_size
from by_your_command.bridge.static_files import (
    StaticSite,
    error_response,
    file_response,
    is_websocket_upgrade,
)
from by_your_command.bridge.tcp_connections import abort_unopened, tracked_connection_class
from by_your_command.net.quiet_websockets import quiet_websocket_logger

log = logging.getLogger(__name__)
# websockets logs request headers (Authorization: the token) at DEBUG: give it a logger that never does.
_QUIET_WEBSOCKET_LOG = quiet_websocket_logger(__name__)

# Frames above the protocol limit get a status error; far larger ones close the connection (1009)
# so a client cannot make us buffer arbitrary amounts before we can say no. websockets counts
# max_size in bytes of the frame payload, so a text frame of multi-byte characters cannot slip by.
HARD_LIMIT_FACTOR = 4
# Frames websockets reads ahead of the handler. While the handler waits (a client's publishes are
# queued behind its conversion) each of them may be up to the hard limit, so keep them few: what
# one client costs is bounded by pending_publish_bytes plus these, not 16 frames of 4 MiB.
READ_AHEAD_FRAMES = 2
_WILDCARD_HOSTS = {"", "0.0.0.0", "::"}


def normalize_origin(origin: str) -> str:
    """`HTTP://LocalHost:9090/` → `http://localhost:9090` (scheme and host are case-insensitive)."""
    return origin.strip().rstrip("/").lower()


def own_origins(host: str, port: int) -> set[str]:
    """The origins of a page the bridge itself serves (the monitor page) on its own port."""
    names = {"127.0.0.1", "localhost", "[::1]"}
    if host not in _WILDCARD_HOSTS and not is_loopback(host):
        names.add(f"[{host}]" if ":" in host else host)
    return {normalize_origin(f"http://{name}:{port}") for name in names}


class BridgeServer:
    def __init__(self, core: BridgeCore, token: str, site: StaticSite | None = None) -> None:
        self.core = core
        self._token = token
        self._site = site  # plain HTTP GETs (the monitor page); None: only WebSocket handshakes
        self._server: Server | None = None
        self._allowed_origins: set[str] = set()
        # Connections admitted and not yet gone, counted from the handshake on: admission is one
        # synchronous check-and-add, so concurrent handshakes cannot exceed max_clients.
        self._admitted: set[ServerConnection] = set()
        self._watchers: set[asyncio.Task[None]] = set()
        self._connections: set[ServerConnection] = set()  # every TCP connection, handshake or not
        self._log_limiter = LogLimiter(core.params.refusal_logs_per_s)
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
            max_queue=READ_AHEAD_FRAMES,
            process_request=self._admit,
            open_timeout=params.handshake_timeout_s,
            ping_interval=params.ping_interval_s or None,
            close_timeout=2,  # a client that stopped reading must not hold up shutdown for long
            logger=_QUIET_WEBSOCKET_LOG,
            create_connection=tracked_connection_class(self._connections),
        )
        self._allowed_origins = {normalize_origin(o) for o in params.allowed_origins} | own_origins(
            params.host, self.port
        )
        log.info(
            "bridge listening on %s:%d (token %s)",
            params.host,
            self.port,
            "required" if self._token else "not required",
        )

    async def stop(self) -> None:
        if self._server is not None:
            # Stop accepting first, so no connection arrives after the unopened ones are dropped;
            # websockets would wait for each of those until its handshake timeout.
            self._server.server.close()
            unopened = abort_unopened(self._connections)
            if unopened:
                log.info("closed %d connection(s) that never completed a handshake", unopened)
            self._server.close()  # open connections get 1001 (going away)
            await self._server.wait_closed()
        watchers = list(self._watchers)
        for watcher in watchers:
            watcher.cancel()
        await asyncio.gather(*watchers, return_exceptions=True)  # none left pending on the loop
        self.core.shutdown()

    @property
    def admitted(self) -> int:
        return len(self._admitted)

    @property
    def tcp_connections(self) -> int:
        """Open TCP connections, also those that never sent a handshake."""
        return len(self._connections)

    def _admit(self, connection: ServerConnection, request: Request) -> Response | None:
        """Runs before the handshake completes: foreign browser origin, wrong token or too many
        clients → HTTP refusal. Synchronous: nothing else runs between the check and the count.
        A request that is not a WebSocket upgrade is a page request: answered here, never admitted."""
        peer = _peer(connection)
        if not is_websocket_upgrade(request.headers):
            return self._serve_page(peer, request)
        refusal = self._check_origin_and_token(peer, request)
        if refusal is not None:
            return refusal
        if len(self._admitted) >= self.core.params.max_clients:
            self._refused(peer, f"already {self.core.params.max_clients} clients")
            return _refusal(HTTPStatus.SERVICE_UNAVAILABLE, "too many bridge clients\n")
        self._admitted.add(connection)
        watcher = asyncio.get_running_loop().create_task(self._release_when_closed(connection))
        self._watchers.add(watcher)
        watcher.add_done_callback(self._watchers.discard)
        return None

    def _check_origin_and_token(
        self, peer: str, request: Request, token_needed: bool = True
    ) -> Response | None:
        # A credential header given twice is ambiguous (which one counts?): refuse it plainly.
        for name in ("Origin", "Authorization"):
            if len(request.headers.get_all(name)) > 1:
                self._refused(peer, f"repeated {name} header")
                return _refusal(HTTPStatus.BAD_REQUEST, f"the {name} header may appear only once\n")
        origin = request.headers.get("Origin")
        # A browser always sends Origin; agents and roslibpy send none. A page from anywhere else
        # may not drive the robot, even on loopback and even with a valid (stolen) token.
        if origin is not None and normalize_origin(origin) not in self._allowed_origins:
            self._refused(peer, f"browser origin {preview(origin)} is not allowed")
            return _refusal(HTTPStatus.FORBIDDEN, "this origin may not connect to the bridge\n")
        if not token_needed:
            return None
        presented = presented_token(request.headers.get("Authorization"), request.path)
        if not token_matches(self._token, presented):
            self._refused(peer, f"{'missing' if presented is None else 'wrong'} token")  # never the token
            return _refusal(HTTPStatus.UNAUTHORIZED, "a valid bridge token is required\n")
        return None

    def _serve_page(self, peer: str, request: Request) -> Response:
        """The monitor page's files: same origin and token rules as a WebSocket client."""
        if request.method != "GET":
            return error_response(HTTPStatus.METHOD_NOT_ALLOWED, "only GET is served here\n")
        file = self._site.find(request.path) if self._site is not None else None
        refusal = self._check_origin_and_token(peer, request, token_needed=file is None or not file.public)
        if refusal is not None:
            return refusal
        if file is None:
            return error_response(HTTPStatus.NOT_FOUND, "nothing here: a WebSocket bridge (rosbridge v2)\n")
        return file_response(file)

    def _refused(self, peer: str, reason: str) -> None:
        self.refused_connections += 1
        held = self._log_limiter.allow()  # connection attempts are client-driven: bound the log
        if held is not None:
            suffix = f" ({held} refusal log line(s) suppressed)" if held else ""
            log.warning("refused %s: %s%s", peer, reason, suffix)

    async def _release_when_closed(self, connection: ServerConnection) -> None:
        """Frees the slot of a connection whose handshake failed (the handler never ran)."""
        try:
            await connection.wait_closed()
        finally:
            self._admitted.discard(connection)

    async def _handle(self, connection: ServerConnection) -> None:
        session = self.core.open_session(_peer(connection))
        sender = asyncio.create_task(self._send_loop(connection, session))
        try:
            async for frame in connection:
                self.core.handle_frame(session, frame)
                if not self.core.accepts_more(session):
                    await self.core.wait_accepts_more(session)  # TCP back-pressure on a heavy client
        except ConnectionClosed:
            pass
        except Exception:  # a bug: this client is cut off, the bridge and the others go on
            log.exception("client %d (%s): connection handler failed", session.id, session.peer)
        finally:
            self._admitted.discard(connection)
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
                session.sent_bytes += utf8_size(text)
        except ConnectionClosed:
            pass
        except Exception:  # never a silent dead sender: the client would just stop hearing us
            log.exception("client %d (%s): send loop failed, closing", session.id, session.peer)
            await connection.close(1011, "bridge send loop failed")


def _peer(connection: ServerConnection) -> str:
    address = connection.remote_address
    return f"{address[0]}:{address[1]}" if address else "?"


def _refusal(status: HTTPStatus, body: str) -> Response:
    return error_response(status, body)
