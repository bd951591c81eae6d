"""A real BridgeServer (real sockets, the shipped allow-lists and monitor page) on its own asyncio
thread, with a ROS port that records instead of publishing: the page's tests need no ROS graph."""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from byc_testing import REPO_ROOT

from by_your_command.bridge.config import BridgeParams, TopicRule, load_allow_lists
from by_your_command.bridge.core import BridgeCore
from by_your_command.bridge.server import BridgeServer
from by_your_command.monitor.config import load_monitor_config
from by_your_command.monitor.site import monitor_site

CONFIG_DIR = REPO_ROOT / "by_your_command" / "config"
NAMESPACE = "/robot1"


class RecordingGraph:
    """The core's RosGraph port: remembers subscriptions and publishes (any message is accepted)."""

    def __init__(self) -> None:
        self.subscribed: set[str] = set()
        self.published: list[tuple[str, dict[str, Any]]] = []

    def subscribe(self, rule: TopicRule, full_topic: str) -> None:
        self.subscribed.add(full_topic)

    def unsubscribe(self, full_topic: str) -> None:
        self.subscribed.discard(full_topic)

    def advertise(self, rule: TopicRule, full_topic: str) -> None:
        pass

    def convert(self, rule: TopicRule, msg: dict[str, Any]) -> Any:
        return msg

    def publish(self, rule: TopicRule, full_topic: str, message: Any) -> None:
        self.published.append((full_topic, message))


class LiveBridge:
    def __init__(self, token: str, **params: Any) -> None:
        self.token = token
        self._params = params
        self.allow = load_allow_lists(CONFIG_DIR / "bridge.yaml")
        self.site = monitor_site(load_monitor_config(CONFIG_DIR / "monitor.yaml"))
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._thread.start()
        self.port = 0
        self.graph = RecordingGraph()
        self.server = self._start()

    def _run(self, coroutine: Any) -> Any:
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(30)

    def _start(self) -> BridgeServer:
        async def start() -> BridgeServer:
            self.graph = RecordingGraph()
            core = BridgeCore(
                BridgeParams(**{**self._params, "port": self.port}), self.allow, self.graph, NAMESPACE
            )
            server = BridgeServer(core, self.token, self.site)
            await server.start()
            return server

        server: BridgeServer = self._run(start())
        self.port = server.port
        return server

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def deliver(self, topic: str, msg: dict[str, Any]) -> None:
        """As if `msg` arrived from ROS on `topic` (relative to the bridge's namespace)."""
        text = json.dumps(msg, separators=(",", ":"))
        self.loop.call_soon_threadsafe(self.server.core.deliver, f"{NAMESPACE}/{topic}", text)

    def restart(self) -> None:
        """Stop the server (every client disconnected) and start a new one on the same port."""
        self.stop()
        self.start()

    def stop(self) -> None:
        """Every client disconnected; the port is free until `start()`."""
        self._run(self.server.stop())

    def start(self) -> None:
        """A new server on the same port (a stopped one comes back)."""
        self.server = self._start()

    def close(self) -> None:
        self._run(self.server.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout=10)
        self.loop.close()


@contextmanager
def live_bridge(token: str = "", **params: Any) -> Iterator[LiveBridge]:
    bridge = LiveBridge(token, **params)
    try:
        yield bridge
    finally:
        bridge.close()
