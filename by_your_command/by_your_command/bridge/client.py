"""Agent-side asyncio client for the bridge (no ROS needed): rosbridge v2 over WebSocket.

Keeps its subscriptions and advertisements and replays them after every reconnect; reconnects
with exponential backoff for as long as it runs; buffers received messages in a bounded queue
(oldest dropped and counted when the agent falls behind).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus, WebSocketException

from by_your_command.bridge.protocol import (
    Advertise,
    Incoming,
    ProtocolError,
    Publish,
    Request,
    Status,
    Subscribe,
    Unadvertise,
    Unsubscribe,
    encode_request,
    normalize_type,
    parse_server_frame,
)

log = logging.getLogger(__name__)


class BridgeUnavailable(ConnectionError):
    """The bridge is not connected right now (the client keeps trying in the background)."""


class BridgeRefused(ConnectionError):
    """The bridge refused the handshake (wrong token, too many clients): retrying will not help."""


@dataclass(frozen=True)
class ClientOptions:
    token: str = ""
    receive_queue: int = 1000
    backoff_initial_s: float = 0.1
    backoff_max_s: float = 5.0
    open_timeout_s: float = 5.0
    max_message_bytes: int = 16 * 1024 * 1024
    retry_refusals: bool = False  # a 401 is a configuration error, not a transient one


class BridgeClient:
    def __init__(
        self,
        url: str,
        options: ClientOptions | None = None,
        on_status: Callable[[Status], None] | None = None,
    ) -> None:
        self.url = url
        self.options = options or ClientOptions()
        self._on_status = on_status
        self._subscriptions: dict[str, Subscribe] = {}
        self._advertised: dict[str, Advertise] = {}
        self._inbox: asyncio.Queue[Incoming] = asyncio.Queue()
        self._connection: ClientConnection | None = None
        self._connected = asyncio.Event()
        self._runner: asyncio.Task[None] | None = None
        self.refusal: BridgeRefused | None = None
        self.statuses: list[Status] = []  # recent bridge statuses (bounded), newest last
        self.dropped = 0
        self.connects = 0

    # --- lifecycle ---------------------------------------------------------------------------

    async def start(self) -> None:
        if self._runner is None:
            self._runner = asyncio.create_task(self._run())

    async def wait_connected(self, timeout: float | None = None) -> None:
        waiter = asyncio.ensure_future(self._connected.wait())
        others = [self._runner] if self._runner else []
        done, _ = await asyncio.wait({waiter, *others}, timeout=timeout, return_when=asyncio.FIRST_COMPLETED)
        if waiter not in done:
            waiter.cancel()
            if self.refusal is not None:
                raise self.refusal
            raise BridgeUnavailable(f"not connected to {self.url} within {timeout} s")

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    async def close(self) -> None:
        if self._runner is not None:
            self._runner.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._runner
            self._runner = None
        if self._connection is not None:
            await self._connection.close()
        self._connected.clear()

    async def __aenter__(self) -> BridgeClient:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # --- requests ----------------------------------------------------------------------------

    async def subscribe(
        self, topic: str, msg_type: str | None = None, throttle_rate_ms: int = 0, queue_length: int = 0
    ) -> None:
        request = Subscribe(
            topic, normalize_type(msg_type) if msg_type else None, throttle_rate_ms, queue_length
        )
        self._subscriptions[topic] = request
        await self._send_if_connected(request)

    async def unsubscribe(self, topic: str) -> None:
        if self._subscriptions.pop(topic, None) is not None:
            await self._send_if_connected(Unsubscribe(topic))

    async def advertise(self, topic: str, msg_type: str) -> None:
        request = Advertise(topic, normalize_type(msg_type))
        self._advertised[topic] = request
        await self._send_if_connected(request)

    async def unadvertise(self, topic: str) -> None:
        if self._advertised.pop(topic, None) is not None:
            await self._send_if_connected(Unadvertise(topic))

    async def publish(self, topic: str, msg: dict[str, Any]) -> None:
        """Send now or raise BridgeUnavailable: stale commands must not be replayed later."""
        connection = self._connection
        if connection is None or not self.connected:
            raise BridgeUnavailable(f"cannot publish on {topic!r}: not connected to {self.url}")
        try:
            await connection.send(encode_request(Publish(topic, msg)))
        except ConnectionClosed as error:
            raise BridgeUnavailable(f"connection lost while publishing on {topic!r}") from error

    async def receive(self, timeout: float | None = None) -> Incoming:
        return await asyncio.wait_for(self._inbox.get(), timeout)

    def receive_nowait(self) -> Incoming | None:
        try:
            return self._inbox.get_nowait()
        except asyncio.QueueEmpty:
            return None

    # --- internals ---------------------------------------------------------------------------

    async def _send_if_connected(self, request: Request) -> None:
        connection = self._connection
        if connection is not None and self.connected:
            with contextlib.suppress(ConnectionClosed):  # replayed on the next connect
                await connection.send(encode_request(request))

    async def _run(self) -> None:
        delay = self.options.backoff_initial_s
        headers = {"Authorization": f"Bearer {self.options.token}"} if self.options.token else None
        while True:
            try:
                async with connect(
                    self.url,
                    additional_headers=headers,
                    compression=None,
                    max_size=self.options.max_message_bytes,
                    open_timeout=self.options.open_timeout_s,
                    proxy=None,  # the bridge is local or on the robot LAN, never behind a web proxy
                ) as connection:
                    self._connection = connection
                    replay: list[Request] = [*self._advertised.values(), *self._subscriptions.values()]
                    for request in replay:
                        await connection.send(encode_request(request))
                    self.connects += 1
                    self._connected.set()
                    delay = self.options.backoff_initial_s
                    log.info("connected to %s", self.url)
                    await self._read(connection)
            except InvalidStatus as error:
                status = error.response.status_code
                if not self.options.retry_refusals and status in (401, 403):
                    self.refusal = BridgeRefused(f"bridge refused the connection: HTTP {status}")
                    log.error("%s", self.refusal)
                    return
                log.warning("bridge refused the connection (HTTP %d); retrying", status)
            except (OSError, WebSocketException, TimeoutError) as error:
                log.debug("bridge connection failed: %s", error)
            finally:
                self._connected.clear()
                self._connection = None
            await asyncio.sleep(delay)
            delay = min(delay * 2, self.options.backoff_max_s)

    async def _read(self, connection: ClientConnection) -> None:
        with contextlib.suppress(ConnectionClosed):
            async for frame in connection:
                try:
                    item = parse_server_frame(frame)
                except ProtocolError as error:
                    log.warning("ignoring a frame from the bridge: %s", error)
                    continue
                if isinstance(item, Status):
                    self._status(item)
                else:
                    self._enqueue(item)

    def _enqueue(self, item: Incoming) -> None:
        if self._inbox.qsize() >= self.options.receive_queue:
            self._inbox.get_nowait()  # the agent is behind: the oldest message is the least useful
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 100 == 0:
                log.warning("receive queue full: %d message(s) dropped so far", self.dropped)
        self._inbox.put_nowait(item)

    def _status(self, status: Status) -> None:
        self.statuses = [*self.statuses[-99:], status]
        if status.level != "info":
            log.warning("bridge %s [%s]: %s", status.level, status.code or "-", status.msg)
        if self._on_status is not None:
            self._on_status(status)
