"""ros_ai_bridge: rosbridge-v2 WebSocket server between the ROS graph and agents (docs/bridge.md).

Thin node: ROS parameters in, `BridgeCore`/`BridgeServer` (pure, in bridge/) on an asyncio loop
in a thread, rclpy callbacks handed over with `call_soon_threadsafe`. Publishers are created at
startup, so a client's first publish is not lost to discovery, and so are the subscriptions of
every topic but the `audio` class (state topics keep their last value for late clients). Audio
topics are subscribed in ROS only while a client wants them, so their publishers see whether
anybody listens (a `prompt_voice` subscriber means an agent).
Losses before the bridge are counted from gaps in each message's publication sequence number
(while the topic has one publisher) and reported to the topic's subscribers; a state topic whose
last publisher leaves has its cached value forgotten.
The node also serves the live monitor page on the same port (monitor/, docs/monitor.md) and
summarises the agents' `agent_metrics` records into /diagnostics and the latched `agent_summary`.
Robot tools (docs/tools.md): the node loads `tools_path`, publishes the catalog on the latched
`robot_tools` and allow-lists the tools' services, actions and topics; clients call services and
send action goals through it (nodes/_bridge_calls.py). A `safety_stop` message cancels every goal.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from by_your_command_msgs.msg import SafetyStop
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.event_handler import QoSSubscriptionMatchedInfo, SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSHistoryPolicy, QoSProfile
from std_msgs.msg import String

from by_your_command.bridge.calls import ActionRule, CallOutcome, ServiceRule
from by_your_command.bridge.config import AllowLists, BridgeParams, ConfigError, TopicRule, load_allow_lists
from by_your_command.bridge.core import BridgeCore, PublishError
from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.server import BridgeServer
from by_your_command.bridge.static_files import StaticSite
from by_your_command.monitor.config import MonitorConfig, MonitorParams, load_monitor_config
from by_your_command.monitor.site import monitor_site
from by_your_command.monitor.summary import WARN, AgentSummary, StatusReport
from by_your_command.nodes import _qos
from by_your_command.nodes._bridge_calls import RosCalls
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._runtime import run_node
from by_your_command.ros.convert import ConversionError, Part, from_dict, message_class, to_dict
from by_your_command.ros.interfaces import describe
from by_your_command.tools.catalog import Catalog, build_catalog
from by_your_command.tools.config import load_tools_config

_QOS = {"stream": _qos.STREAM, "reliable": _qos.RELIABLE, "latched": _qos.LATCHED}
STARTUP_TIMEOUT_S = 10.0
# The server's own stop is bounded (open connections get close_timeout, 2 s); whatever is still
# running after SERVER_STOP_TIMEOUT_S is cancelled, within STOP_TIMEOUT_S in all.
SERVER_STOP_TIMEOUT_S = 4.0
STOP_TIMEOUT_S = 5.0
# ROS messages handed to the loop and not yet routed: beyond this the loop is hopelessly behind,
# and further messages are counted as lost instead of growing the loop's queue without bound.
MAX_IN_FLIGHT = 4096
TOOLS_TOPIC = "robot_tools"  # relative: the catalog of this bridge's robot, latched
SAFETY_STOP_TOPIC = "safety_stop"  # relative: the VAD heard "stop"


def tool_allow_lists(catalog: Catalog) -> AllowLists:
    """What the tools call: their services and actions (with the tool's timeout), their topics as
    publishable commands. Merged into bridge.yaml's allow-lists."""
    services: list[ServiceRule] = []
    actions: list[ActionRule] = []
    publish: list[TopicRule] = []
    for tool in catalog.tools:
        timeout_s = float(tool.rules.timeout_s)
        if tool.kind == "service":
            services.append(ServiceRule(tool.ros_name, tool.type, timeout_s))
        elif tool.kind == "action":
            actions.append(ActionRule(tool.ros_name, tool.type, timeout_s))
        elif tool.kind == "topic":
            publish.append(TopicRule(tool.ros_name, tool.type, "command", "reliable"))
    return AllowLists(publish=tuple(publish), services=tuple(services), actions=tuple(actions))


def subscription_qos(rule: TopicRule, audio_history_depth: int) -> QoSProfile:
    """Audio is reliable and bursty (agents read faster than real time): a deeper history keeps
    DDS from overwriting chunks while the bridge converts the previous ones."""
    profile = _QOS[rule.qos]
    if rule.topic_class != "audio" or profile.depth >= audio_history_depth:
        return profile
    return QoSProfile(
        history=QoSHistoryPolicy.KEEP_LAST,
        depth=audio_history_depth,
        reliability=profile.reliability,
        durability=profile.durability,
    )


class SequenceGaps:
    """Counts messages lost upstream from gaps in `publication_sequence_number` (per publisher,
    +1 per message). Only trusted while the topic has exactly one matched publisher: sequences of
    two publishers interleave, and message info does not say which publisher sent a message."""

    def __init__(self) -> None:
        self.publishers = 0
        # The last publisher left: a message still in the reader's queue, taken after the unmatch
        # event, is not the current state (the publisher that made it is gone).
        self.departed = False
        self._last: int | None = None

    def matched(self, current_count: int) -> None:
        self.publishers = current_count
        self.departed = current_count == 0
        self._last = None  # a publisher came or went: start a new baseline

    def lost_before(self, sequence: int | None) -> int:
        if sequence is None or self.publishers != 1:
            self._last = None
            return 0
        last, self._last = self._last, sequence
        if last is None or sequence <= last:
            return 0  # first message seen, or the publisher restarted
        return sequence - last - 1


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

    def __init__(self, node: Node, loop: asyncio.AbstractEventLoop, audio_history_depth: int) -> None:
        self._node = node
        self._loop = loop
        self._audio_history_depth = audio_history_depth
        self._publishers: dict[str, Publisher] = {}
        self._classes: dict[str, Any] = {}  # by type name; filled at startup, read by worker threads
        self._always: set[str] = set()
        self._wanted: set[str] = set()  # read by rclpy callbacks: set membership is atomic under the GIL
        self._gaps: dict[str, SequenceGaps] = {}
        self._rules: dict[str, TopicRule] = {}
        self._subscriptions: dict[str, Any] = {}
        # Hand-offs to the loop: `_posted` is written only by the rclpy thread, `_routed` only by the
        # loop, so their difference is the backlog without a lock.
        self._posted = 0
        self._routed = 0
        self.core: BridgeCore | None = None
        self.conversion_errors = 0
        self.callback_errors = 0
        self.calls = RosCalls(node, loop)
        self._executor_stopped = False

    def create_entities(
        self, subscribe: list[tuple[TopicRule, str]], publish: list[tuple[TopicRule, str]]
    ) -> None:
        for rule, full in subscribe:
            self._classes[rule.type] = message_class(rule.type)  # an unknown type stops the start
            self._rules[full] = rule
            if rule.topic_class == "state":
                self._always.add(full)  # the core remembers the current state for late subscribers
                self._wanted.add(full)
            if rule.topic_class != "audio":
                # Matched long before a client needs it: a verdict or prompt published right after
                # an agent connects is not lost to DDS discovery. Audio is subscribed on demand.
                self._create_subscription(full)
        for rule, full in publish:
            cls = message_class(rule.type)
            self._classes[rule.type] = cls
            self._publishers[full] = self._node.create_publisher(cls, full, _QOS[rule.qos])

    def _on_matched(self, full: str) -> Any:
        def matched(info: QoSSubscriptionMatchedInfo) -> None:
            self._gaps[full].matched(info.current_count)
            if info.current_count == 0 and self.core is not None:
                try:
                    self._post(self.core.forget_state, full)
                except RuntimeError:
                    pass  # the loop is closed: the node is shutting down

        return matched

    def _forwarder(self, full: str) -> Any:
        gaps = self._gaps[full]

        def forward(msg: Any, info: dict[str, Any]) -> None:
            if self.core is None:
                return
            try:
                lost = gaps.lost_before(info.get("publication_sequence_number"))
                if lost:  # before the message that revealed the gap: the report reaches clients first
                    self._post(self.core.report_lost, full, lost)
                if full not in self._wanted:
                    return
                if self._posted - self._routed >= MAX_IN_FLIGHT:
                    self._post(self.core.report_lost, full, 1)
                    return
                try:
                    text = json.dumps(to_dict(msg), separators=(",", ":"), allow_nan=False)
                except (ValueError, TypeError) as error:
                    self.conversion_errors += 1
                    self._node.get_logger().error(f"cannot convert a message on {full}: {error}")
                    return
                self._loop.call_soon_threadsafe(self._route, full, text, not gaps.departed)
                self._posted += 1
            except RuntimeError:
                pass  # the loop is closed: the node is shutting down
            except Exception as error:  # an exception here would stop the executor (and the node)
                self.callback_errors += 1
                self._node.get_logger().error(f"forwarding a message on {full} failed: {error!r}")

        return forward

    def _post(self, callback: Any, *args: Any) -> None:
        self._loop.call_soon_threadsafe(callback, *args)

    def _route(self, full: str, text: str, current: bool) -> None:
        self._routed += 1
        if self.core is not None:
            self.core.deliver(full, text, current)

    def subscribe(self, rule: TopicRule, full_topic: str) -> None:
        self._create_subscription(full_topic)
        self._wanted.add(full_topic)

    def unsubscribe(self, full_topic: str) -> None:
        if full_topic in self._always:
            return
        self._wanted.discard(full_topic)
        if self._rules[full_topic].topic_class == "audio":
            # Nobody wants this audio: drop the ROS subscription too, so its publisher sees that
            # nobody listens (the VAD reports an utterance nobody hears; a file source waits).
            subscription = self._subscriptions.pop(full_topic, None)
            if subscription is not None:
                self._destroy_subscription(subscription)

    def _destroy_subscription(self, subscription: Any) -> None:
        # Destroyed on the executor's thread: from the loop thread it races the executor's wait set,
        # which may hold the handle already ("InvalidHandle: destruction was requested" kills the
        # executor thread). Once the executor has stopped nothing spins: destroy it here.
        executor = None if self._executor_stopped else self._node.executor
        if executor is None:
            self._node.destroy_subscription(subscription)
        else:
            executor.create_task(self._node.destroy_subscription, subscription)

    def executor_stopped(self) -> None:
        """From here on rclpy is called from the loop thread (the executor no longer runs tasks)."""
        self._executor_stopped = True
        self.calls.executor_stopped()

    def _create_subscription(self, full: str) -> None:
        if full in self._subscriptions:
            return
        rule = self._rules[full]
        self._gaps[full] = SequenceGaps()
        self._subscriptions[full] = self._node.create_subscription(
            self._classes[rule.type],
            full,
            self._forwarder(full),
            subscription_qos(rule, self._audio_history_depth),
            event_callbacks=SubscriptionEventCallbacks(matched=self._on_matched(full)),
        )

    def sources(self) -> dict[str, int]:
        """Matched publishers of each ROS subscription (ROS topics → clients), by full topic name."""
        return {full: sub.get_publisher_count() for full, sub in list(self._subscriptions.items())}

    def listeners(self) -> dict[str, int]:
        """Matched subscribers of each publisher (clients → ROS topics), by full topic name."""
        return {full: publisher.get_subscription_count() for full, publisher in self._publishers.items()}

    def advertise(self, rule: TopicRule, full_topic: str) -> None:
        pass  # publishers exist from startup

    def convert(self, rule: TopicRule, msg: dict[str, Any]) -> Any:
        try:
            return from_dict(self._classes[rule.type], msg)
        except ConversionError as error:
            raise PublishError(str(error)) from None

    def publish(self, rule: TopicRule, full_topic: str, message: Any) -> None:
        try:
            self._publishers[full_topic].publish(message)
        except Exception as error:  # rclpy raises plain RCLError/RuntimeError under overload
            raise PublishError(f"ROS publish failed: {error}") from None

    # Service calls and action goals: nodes/_bridge_calls.py.

    def convert_call(self, type_name: str, part: Part, args: dict[str, Any]) -> Any:
        return self.calls.convert_call(type_name, part, args)

    def call_service(
        self,
        rule: ServiceRule,
        full_name: str,
        request: Any,
        timeout_s: float,
        done: Callable[[CallOutcome], None],
    ) -> None:
        self.calls.call_service(rule, full_name, request, timeout_s, done)

    def send_goal(
        self,
        rule: ActionRule,
        full_name: str,
        goal: Any,
        token: int,
        feedback: Callable[[str], None],
        done: Callable[[CallOutcome], None],
    ) -> None:
        self.calls.send_goal(rule, full_name, goal, token, feedback, done)

    def cancel_goal(self, token: int) -> None:
        self.calls.cancel_goal(token)


class RosAiBridge(Node):
    def __init__(self) -> None:
        super().__init__("ros_ai_bridge")
        self.params = declare_config(self, BridgeParams)
        self.monitor_params = declare_config(self, MonitorParams)
        token = self.params.token or os.environ.get(self.params.token_env, "")
        catalog = self._load_tools()
        allow = load_allow_lists(self._config_path()).merged(tool_allow_lists(catalog))
        monitor = load_monitor_config(self._monitor_config_path())
        namespace = self.get_namespace()

        self._log_handler = _RclpyLogHandler(self)
        bridge_log = logging.getLogger("by_your_command.bridge")
        bridge_log.addHandler(self._log_handler)
        bridge_log.setLevel(logging.INFO)

        self._loop = asyncio.new_event_loop()
        self._graph = _NodeGraph(self, self._loop, self.params.audio_history_depth)
        self._graph.create_entities(
            [(rule, resolve_topic(rule.topic, namespace)) for rule in allow.subscribe],
            [(rule, resolve_topic(rule.topic, namespace)) for rule in allow.publish],
        )
        self._graph.calls.prepare(
            [(rule.type, resolve_topic(rule.name, namespace)) for rule in allow.services],
            [(rule.type, resolve_topic(rule.name, namespace)) for rule in allow.actions],
        )
        self.core = BridgeCore(self.params, allow, self._graph, namespace)
        self._graph.core = self.core
        # Latched: an agent that connects any time later still learns what the robot can do.
        self._tools_pub = self.create_publisher(String, TOOLS_TOPIC, _qos.LATCHED)
        self._tools_pub.publish(String(data=catalog.to_json()))
        self.create_subscription(SafetyStop, SAFETY_STOP_TOPIC, self._on_safety_stop, _qos.RELIABLE)
        site: StaticSite | None = monitor_site(monitor) if self.monitor_params.monitor_page else None
        self.server = BridgeServer(self.core, token, site)
        self._setup_summary(monitor, namespace)
        self._diagnostics = (
            self.create_publisher(DiagnosticArray, self.params.diagnostics_topic, _qos.RELIABLE)
            if self.params.diagnostics_period_s > 0
            else None
        )
        self._diagnostics_task: asyncio.Task[None] | None = None
        self._summary_task: asyncio.Task[None] | None = None
        self._reported_losses = 0  # WARN while drops/losses grow, OK again once they stop
        self._thread = threading.Thread(target=self._loop.run_forever, name="bridge-asyncio", daemon=True)
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self._start(), self._loop).result(STARTUP_TIMEOUT_S)
        self.get_logger().info(
            f"ros_ai_bridge ready on {self.params.host}:{self.server.port} "
            f"({len(allow.subscribe)} subscribable, {len(allow.publish)} publishable topics, "
            f"{len(allow.services)} services, {len(allow.actions)} actions; "
            f"{len(catalog.tools)} robot tools on {self._tools_pub.topic_name})"
        )

    def _load_tools(self) -> Catalog:
        """The tools file → the catalog; a bad file (or an interface that is not installed) stops
        the start with the file's name and what is wrong, like the other config errors."""
        path = _installed_or(self.params.tools_path, "tools.yaml", "tools_path")
        try:
            return build_catalog(load_tools_config(path), describe)
        except ValueError as error:  # ToolsConfigError names the tool and the key
            raise ConfigError(f"robot tools {path}: {error}") from None

    def _on_safety_stop(self, msg: SafetyStop) -> None:
        try:
            self._loop.call_soon_threadsafe(self._safety_stop, msg.phrase)
        except RuntimeError:
            pass  # the loop is closed: the node is shutting down

    def _safety_stop(self, reason: str) -> None:
        cancelled = self.core.cancel_all_goals(f"safety stop: {reason}")
        self.get_logger().info(f"safety stop ({reason[:80]!r}): cancelled {cancelled} goal(s)")

    def _config_path(self) -> Path:
        return _installed_or(self.params.config_path, "bridge.yaml", "config_path")

    def _monitor_config_path(self) -> Path:
        return _installed_or(self.monitor_params.monitor_config_path, "monitor.yaml", "monitor_config_path")

    def _setup_summary(self, monitor: MonitorConfig, namespace: str) -> None:
        """agent_metrics → AgentSummary (on the loop thread, like the core) → diagnostics + summary topic."""
        params = self.monitor_params
        self.summary = AgentSummary(monitor.prices, monitor.currency, monitor.page.latency_turns)
        self._metrics_topic = resolve_topic(params.metrics_topic, namespace)
        self._summary_errors = 0
        self._summary_pub = (
            self.create_publisher(String, resolve_topic(params.summary_topic, namespace), _qos.LATCHED)
            if params.summary_topic
            else None
        )
        self.create_subscription(String, self._metrics_topic, self._on_metrics, _qos.RELIABLE)

    def _on_metrics(self, msg: String) -> None:
        try:
            self._loop.call_soon_threadsafe(self._feed_summary, msg.data)
        except RuntimeError:
            pass  # the loop is closed: the node is shutting down

    def _feed_summary(self, text: str) -> None:
        try:
            self.summary.feed(text)
        except Exception as error:  # a bug must not end the loop's callbacks; counted in diagnostics
            self._summary_errors += 1
            self.get_logger().error(f"summarising an agent_metrics record failed: {error!r}")

    def agents_connected(self) -> int:
        """Bridge clients that advertised the metrics topic: every agent does when it connects."""
        return sum(1 for session in self.core.sessions if self._metrics_topic in session.advertised)

    async def _start(self) -> None:
        await self.server.start()
        if self._diagnostics is not None:
            self._diagnostics_task = asyncio.create_task(self._publish_diagnostics())
        if self._summary_pub is not None:
            self._summary_task = asyncio.create_task(self._publish_summary())

    async def _stop(self) -> None:
        for task in (self._diagnostics_task, self._summary_task):
            if task is not None:
                task.cancel()
        try:
            await asyncio.wait_for(self.server.stop(), SERVER_STOP_TIMEOUT_S)
        finally:
            self._graph.calls.destroy()
            # Nothing may stay pending when the loop stops: a task destroyed pending runs its
            # cleanup at exit, without a loop ("Task was destroyed but it is pending!").
            await _cancel_other_tasks()

    async def _publish_summary(self) -> None:
        """The latched summary, whenever it changed (checked every summary_period_s)."""
        assert self._summary_pub is not None
        published: tuple[int, int] | None = None
        while True:
            try:
                connected = self.agents_connected()
                if published != (self.summary.version, connected):
                    text = json.dumps(self.summary.snapshot(connected), separators=(",", ":"))
                    self._summary_pub.publish(String(data=text))
                    published = (self.summary.version, connected)
            except Exception as error:  # keep summarising: one failure must not end it
                self._summary_errors += 1
                self.get_logger().error(f"cannot publish the agent summary: {error!r}")
            await asyncio.sleep(self.monitor_params.summary_period_s)

    async def _publish_diagnostics(self) -> None:
        assert self._diagnostics is not None
        while True:
            await asyncio.sleep(self.params.diagnostics_period_s)
            try:
                self._diagnostics.publish(self._diagnostic_array())
            except Exception as error:  # keep reporting: one failed publish must not end diagnostics
                self.get_logger().error(f"cannot publish diagnostics: {error!r}")

    def _diagnostic_array(self) -> DiagnosticArray:
        stats = self.core.stats()
        totals = self.core.totals()  # cumulative: clients that dropped messages and left still count
        lost_now = totals.dropped + totals.lost_upstream
        warn = lost_now > self._reported_losses
        self._reported_losses = lost_now
        values = {
            "clients": len(stats),
            "connections_total": totals.connections,
            "refused_connections": self.server.refused_connections,
            "ros_messages_delivered": self.core.delivered,
            "conversion_errors": self._graph.conversion_errors,
            "callback_errors": self._graph.callback_errors,
            "internal_errors": totals.internal_errors,
            "dropped_total": totals.dropped,
            "lost_upstream_total": totals.lost_upstream,
            "rejected_total": totals.rejected,
            "status_suppressed_total": totals.status_suppressed,
            "received_total": totals.received,
            "sent_messages_total": totals.sent_messages,
            "sent_bytes_total": totals.sent_bytes,
            "subscribed_topics": ",".join(self.core.subscribed_topics()),
            # service calls and action goals: the core's counts, then the ROS side's
            "service_calls_total": totals.service_calls,
            "service_failures_total": totals.service_failures,
            "goals_sent_total": totals.goals_sent,
            "goals_active": totals.goals_active,
            "goals_succeeded_total": totals.goals_succeeded,
            "goals_failed_total": totals.goals_failed,
            "goals_cancelled_total": totals.goals_cancelled,
            "feedback_dropped_total": totals.feedback_dropped,
            "replies_discarded_total": totals.replies_discarded,
            "ros_goals_tracked": self._graph.calls.active_goals,
            "feedback_coalesced_total": self._graph.calls.feedback_coalesced,
            "late_goal_answers_total": self._graph.calls.late_answers,
            "call_callback_errors": self._graph.calls.callback_errors,
        }
        for topic, count in sorted(self.core.lost_upstream.items()):
            values[f"lost_upstream.{topic}"] = count
        # Who listens to what clients publish: 0 means a reply or command would go nowhere.
        for topic, listeners in sorted(self._graph.listeners().items()):
            values[f"listeners.{topic}"] = listeners
        for topic, sources in sorted(self._graph.sources().items()):
            values[f"sources.{topic}"] = sources
        # Whether each service's / action's server is there: 0 means a call would get no_server.
        for name, ready in sorted(self._graph.calls.servers().items()):
            values[f"servers.{name}"] = ready
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
                    f"{prefix}.lost": client.lost,
                    f"{prefix}.status_suppressed": client.status_suppressed,
                    f"{prefix}.pending_publishes": client.pending_publishes,
                    f"{prefix}.pending_calls": client.pending_calls,
                    f"{prefix}.active_goals": client.active_goals,
                    f"{prefix}.service_calls": client.service_calls,
                    f"{prefix}.goals_sent": client.goals_sent,
                    f"{prefix}.feedback_dropped": client.feedback_dropped,
                }
            )
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if warn else DiagnosticStatus.OK,
            name=f"{self.get_fully_qualified_name()}: websocket bridge",
            message=(
                f"{len(stats)} client(s); since start {totals.dropped} dropped, "
                f"{totals.lost_upstream} lost before the bridge"
            ),
            hardware_id="",
            values=[KeyValue(key=key, value=str(value)) for key, value in values.items()],
        )
        agents = [
            _diagnostic_status(report, self.get_fully_qualified_name()) for report in self._agent_reports()
        ]
        array = DiagnosticArray(status=[status, *agents])
        array.header.stamp = self.get_clock().now().to_msg()
        return array

    def _agent_reports(self) -> list[StatusReport]:
        reports = self.summary.reports(self.agents_connected())
        if self._summary_errors:
            reports[0].values["summary_errors"] = str(self._summary_errors)
        return reports

    async def _cancel_goals(self, reason: str) -> int:
        return self.core.cancel_all_goals(reason)

    def before_shutdown(self) -> None:
        """run_node: the executor has stopped. Goals still running are cancelled (nobody will be
        left to stop the robot), from the loop thread now that no executor thread calls rclpy."""
        self._graph.executor_stopped()
        if self._loop.is_running():
            cancelled = asyncio.run_coroutine_threadsafe(
                self._cancel_goals("the bridge is stopping"), self._loop
            ).result(STOP_TIMEOUT_S)
            if cancelled:
                self.get_logger().info(f"cancelled {cancelled} goal(s): the bridge is stopping")

    def destroy_node(self) -> None:
        # The node is going away (its logger will not publish any more): stop routing to it.
        logging.getLogger("by_your_command.bridge").removeHandler(self._log_handler)
        if self._loop.is_running():
            try:
                asyncio.run_coroutine_threadsafe(self._stop(), self._loop).result(STOP_TIMEOUT_S)
            except Exception as error:  # shutting down anyway; say why it was not clean
                # repr: a timeout's message is empty, and "did not stop cleanly: " explains nothing
                self.get_logger().warning(f"bridge server did not stop cleanly: {error!r}")
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=5.0)
        super().destroy_node()


async def _cancel_other_tasks() -> None:
    others = asyncio.all_tasks() - {asyncio.current_task()}
    for task in others:
        task.cancel()
    await asyncio.gather(*others, return_exceptions=True)


def _installed_or(path: str, file_name: str, parameter: str) -> Path:
    if path:
        return Path(path)
    try:
        return Path(get_package_share_directory("by_your_command")) / "config" / file_name
    except PackageNotFoundError:
        raise RuntimeError(f"{parameter} is empty and by_your_command is not installed") from None


def _diagnostic_status(report: StatusReport, node_name: str) -> DiagnosticStatus:
    return DiagnosticStatus(
        level=DiagnosticStatus.WARN if report.level == WARN else DiagnosticStatus.OK,
        name=f"{node_name}: {report.name}",
        message=report.message,
        hardware_id="",
        values=[KeyValue(key=key, value=value) for key, value in report.values.items()],
    )


# Large conversions run on worker threads that hold the GIL; Python hands it to the waiting event
# loop only every switch interval (5 ms by default), which every light client would wait for.
GIL_SWITCH_INTERVAL_S = 0.0005


def main(args: list[str] | None = None) -> None:
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    run_node(RosAiBridge, args)


if __name__ == "__main__":
    main()
