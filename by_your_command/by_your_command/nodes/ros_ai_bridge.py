"""ros_ai_bridge: rosbridge-v2 WebSocket server between the ROS graph and agents (docs/bridge.md).

Thin node: ROS parameters in, `BridgeCore`/`BridgeServer` (pure, in bridge/) on an asyncio loop
in a thread, rclpy callbacks handed over with `call_soon_threadsafe`. All allow-listed ROS
subscriptions and publishers are created at startup, so a client's first publish is not lost to
discovery; messages of topics nobody subscribes to are not even converted.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import threading
from pathlib import Path
from typing import Any

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.publisher import Publisher

from by_your_command.bridge.config import BridgeParams, TopicRule, load_allow_lists
from by_your_command.bridge.core import BridgeCore, PublishError
from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.server import BridgeServer
from by_your_command.nodes import _qos
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._runtime import run_node
from by_your_command.ros.convert import ConversionError, from_dict, message_class, to_dict

_QOS = {"stream": _qos.STREAM, "reliable": _qos.RELIABLE, "latched": _qos.LATCHED}
STARTUP_TIMEOUT_S = 10.0


class _RclpyLogHandler(logging.Handler):
    """Routes the pure bridge modules' `logging` records to this node's logger."""

    def __init__(self, node: Node) -> None:
        super().__init__()
        self._logger = node.get_logger()

    def emit(self, record: logging.LogRecord) -> None:
        text = self.format(record)
        if record.levelno >= logging.ERROR:
            self._logger.error(text)
        elif record.levelno >= logging.WARNING:
            self._logger.warning(text)
        elif record.levelno >= logging.INFO:
            self._logger.info(text)
        else:
            self._logger.debug(text)


class _NodeGraph:
    """The core's RosGraph port on a real node. Called only on the asyncio loop thread."""

    def __init__(self, node: Node, loop: asyncio.AbstractEventLoop) -> None:
        self._node = node
        self._loop = loop
        self._publishers: dict[str, tuple[Publisher, Any]] = {}
        self._always: set[str] = set()
        self._wanted: set[str] = set()  # read by rclpy callbacks: set membership is atomic under the GIL
        self.core: BridgeCore | None = None
        self.conversion_errors = 0

    def create_entities(
        self, subscribe: list[tuple[TopicRule, str]], publish: list[tuple[TopicRule, str]]
    ) -> None:
        for rule, full in subscribe:
            cls = message_class(rule.type)
            if rule.topic_class == "state":
                self._always.add(full)
                self._wanted.add(full)  # the core remembers the current state for late subscribers
            self._node.create_subscription(cls, full, self._forwarder(full), _QOS[rule.qos])
        for rule, full in publish:
            cls = message_class(rule.type)
            self._publishers[full] = (self._node.create_publisher(cls, full, _QOS[rule.qos]), cls)

    def _forwarder(self, full: str) -> Any:
        def forward(msg: Any) -> None:
            if full not in self._wanted or self.core is None:
                return
            try:
                text = json.dumps(to_dict(msg), separators=(",", ":"), allow_nan=False)
            except (ValueError, TypeError) as error:
                self.conversion_errors += 1
                self._node.get_logger().error(f"cannot convert a message on {full}: {error}")
                return
            self._loop.call_soon_threadsafe(self.core.deliver, full, text)

        return forward

    def subscribe(self, rule: TopicRule, full_topic: str) -> None:
        self._wanted.add(full_topic)

    def unsubscribe(self, full_topic: str) -> None:
        if full_topic not in self._always:
            self._wanted.discard(full_topic)

    def advertise(self, rule: TopicRule, full_topic: str) -> None:
        pass  # publishers exist from startup

    def publish(self, rule: TopicRule, full_topic: str, msg: dict[str, Any]) -> None:
        publisher, cls = self._publishers[full_topic]
        try:
            message = from_dict(cls, msg)
        except ConversionError as error:
            raise PublishError(str(error)) from None
        try:
            publisher.publish(message)
        except Exception as error:  # rclpy raises plain RCLError/RuntimeError under overload
            raise PublishError(f"ROS publish failed: {error}") from None


class RosAiBridge(Node):
    def __init__(self) -> None:
        super().__init__("ros_ai_bridge")
        self.params = declare_config(self, BridgeParams)
        token = self.params.token or os.environ.get(self.params.token_env, "")
        allow = load_allow_lists(self._config_path())
        namespace = self.get_namespace()

        self._log_handler = _RclpyLogHandler(self)
        bridge_log = logging.getLogger("by_your_command.bridge")
        bridge_log.addHandler(self._log_handler)
        bridge_log.setLevel(logging.INFO)

        self._loop = asyncio.new_event_loop()
        self._graph = _NodeGraph(self, self._loop)
        self._graph.create_entities(
            [(rule, resolve_topic(rule.topic, namespace)) for rule in allow.subscribe],
            [(rule, resolve_topic(rule.topic, namespace)) for rule in allow.publish],
        )
        self.core = BridgeCore(self.params, allow, self._graph, namespace)
        self._graph.core = self.core
        self.server = BridgeServer(self.core, token)
        self._diagnostics = (
            self.create_publisher(DiagnosticArray, self.params.diagnostics_topic, _qos.RELIABLE)
            if self.params.diagnostics_period_s > 0
            else None
        )
        self._diagnostics_task: asyncio.Task[None] | None = None
        self._thread = threading.Thread(target=self._loop.run_forever, name="bridge-asyncio", daemon=True)
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self._loop).result(STARTUP_TIMEOUT_S)
        self.get_logger().info(
            f"ros_ai_bridge ready on {self.params.host}:{self.server.port} "
            f"({len(allow.subscribe)} subscribable, {len(allow.publish)} publishable topics)"
        )

    def _config_path(self) -> Path:
        if self.params.config_path:
            return Path(self.params.config_path)
        try:
            return Path(get_package_share_directory("by_your_command")) / "config" / "bridge.yaml"
        except PackageNotFoundError:
            raise RuntimeError("config_path is empty and by_your_command is not installed") from None

    async def _start(self) -> None:
        await self.server.start()
        if self._diagnostics is not None:
            self._diagnostics_task = asyncio.create_task(self._publish_diagnostics())

    async def _stop(self) -> None:
        if self._diagnostics_task is not None:
            self._diagnostics_task.cancel()
        await self.server.stop()

    async def _publish_diagnostics(self) -> None:
        assert self._diagnostics is not None
        while True:
            await asyncio.sleep(self.params.diagnostics_period_s)
            self._diagnostics.publish(self._diagnostic_array())

    def _diagnostic_array(self) -> DiagnosticArray:
        stats = self.core.stats()
        dropped = sum(client.dropped for client in stats)
        values = {
            "clients": len(stats),
            "refused_connections": self.server.refused_connections,
            "ros_messages_delivered": self.core.delivered,
            "conversion_errors": self._graph.conversion_errors,
            "dropped_total": dropped,
            "subscribed_topics": ",".join(self.core.subscribed_topics()),
        }
        for client in stats:
            prefix = f"client{client.id}"
            values.update(
                {
                    f"{prefix}.peer": client.peer,
                    f"{prefix}.queue_depth": client.queue_depth,
                    f"{prefix}.queued_bytes": client.queued_bytes,
                    f"{prefix}.sent_messages": client.sent_messages,
                    f"{prefix}.sent_bytes": client.sent_bytes,
                    f"{prefix}.received": client.received,
                    f"{prefix}.rejected": client.rejected,
                    f"{prefix}.dropped": client.dropped,
                }
            )
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if dropped else DiagnosticStatus.OK,
            name=f"{self.get_fully_qualified_name()}: websocket bridge",
            message=f"{len(stats)} client(s), {dropped} dropped",
            hardware_id="",
            values=[KeyValue(key=key, value=str(value)) for key, value in values.items()],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        return array

    def destroy_node(self) -> None:
        # rclpy is already shut down here (its logger cannot publish): stop routing to it.
        logging.getLogger("by_your_command.bridge").removeHandler(self._log_handler)
        if self._loop.is_running():
            try:
                asyncio.run_coroutine_threadsafe(self._stop(), self._loop).result(5.0)
            except Exception as error:  # shutting down anyway; say why it was not clean
                self.get_logger().warning(f"bridge server did not stop cleanly: {error}")
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5.0)
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(RosAiBridge, args)


if __name__ == "__main__":
    main()
