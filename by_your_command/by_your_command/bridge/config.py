"""Bridge settings: ROS parameters (one dataclass, the one place defaults live) and YAML allow-lists."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

import yaml

from by_your_command.bridge.calls import ActionRule, ServiceRule
from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.protocol import (
    MAX_CALL_TIMEOUT_S,
    InterfaceKind,
    normalize_interface,
    normalize_type,
)

TopicClass = Literal["audio", "video", "command", "state", "text"]
QosName = Literal["stream", "reliable", "latched"]
TOPIC_CLASSES: tuple[TopicClass, ...] = ("audio", "video", "command", "state", "text")
QOS_NAMES: tuple[QosName, ...] = ("stream", "reliable", "latched")


@dataclass(frozen=True)
class BridgeParams:
    host: str = field(default="127.0.0.1", metadata={"help": "bind address; non-loopback needs a token"})
    port: int = field(default=9090, metadata={"help": "TCP port (rosbridge's usual 9090); 0 = any free"})
    token: str = field(default="", metadata={"help": "shared secret clients must present (never logged)"})
    token_env: str = field(
        default="BYC_BRIDGE_TOKEN", metadata={"help": "environment variable read when `token` is empty"}
    )
    config_path: str = field(
        default="", metadata={"help": "allow-list YAML; empty = the installed config/bridge.yaml"}
    )
    tools_path: str = field(
        default="",
        metadata={"help": "robot tools YAML (docs/tools.md); empty = the installed config/tools.yaml"},
    )
    max_message_bytes: int = field(default=1_048_576, metadata={"help": "largest accepted inbound frame"})
    max_clients: int = field(default=16, metadata={"help": "connections beyond this are refused"})
    send_queue_messages: int = field(default=256, metadata={"help": "per-client outbound queue bound"})
    send_queue_bytes: int = field(default=16_777_216, metadata={"help": "per-client outbound byte bound"})
    rate_limit_per_s: float = field(default=500.0, metadata={"help": "inbound requests/s per client"})
    rate_burst: int = field(default=1000, metadata={"help": "inbound request burst per client"})
    diagnostics_period_s: float = field(default=1.0, metadata={"help": "0 disables diagnostics"})
    diagnostics_topic: str = field(default="/diagnostics", metadata={"help": "ROS convention: global"})
    ping_interval_s: float = field(default=20.0, metadata={"help": "WebSocket keepalive ping period"})
    handshake_timeout_s: float = field(
        default=10.0, metadata={"help": "a connection that has not completed its handshake by then is closed"}
    )
    allowed_origins: tuple[str, ...] = field(
        default=(),
        metadata={
            "help": "browser Origins allowed to connect (e.g. http://robot.local:8080), besides the "
            "bridge's own http://127.0.0.1:<port> and http://localhost:<port>; clients sending no "
            "Origin (agents, roslibpy) are not affected"
        },
    )
    status_queue_bytes: int = field(
        default=65_536,
        metadata={"help": "per-client bound on queued status replies; beyond it they coalesce"},
    )
    max_json_depth: int = field(default=32, metadata={"help": "deepest JSON nesting accepted from a client"})
    inline_convert_bytes: int = field(
        default=16_384,
        metadata={"help": "publishes up to this size are converted on the event loop, larger on a worker"},
    )
    convert_threads: int = field(default=2, metadata={"help": "worker threads converting large publishes"})
    pending_publish_messages: int = field(
        default=32, metadata={"help": "per client: publishes awaiting conversion before reading pauses"}
    )
    pending_publish_bytes: int = field(
        default=4_194_304, metadata={"help": "per client: bytes awaiting conversion before reading pauses"}
    )
    audio_history_depth: int = field(
        default=1000, metadata={"help": "DDS history depth of the bridge's audio-class subscriptions"}
    )
    refusal_logs_per_s: float = field(
        default=2.0, metadata={"help": "refusal log lines per second (burst 20), the rest are counted"}
    )
    max_pending_calls: int = field(
        default=16, metadata={"help": "per client: service calls awaiting their response; more are refused"}
    )
    max_active_goals: int = field(
        default=8, metadata={"help": "per client: action goals not yet ended; more are refused"}
    )

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ValueError(f"port must be 0..65535, got {self.port}")
        for name in (
            "max_message_bytes",
            "max_clients",
            "send_queue_messages",
            "send_queue_bytes",
            "status_queue_bytes",
            "max_json_depth",
            "convert_threads",
            "pending_publish_messages",
            "pending_publish_bytes",
            "audio_history_depth",
            "max_pending_calls",
            "max_active_goals",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if self.handshake_timeout_s <= 0:
            raise ValueError(f"handshake_timeout_s must be positive, got {self.handshake_timeout_s}")
        if self.inline_convert_bytes < 0:
            raise ValueError(f"inline_convert_bytes must be >= 0, got {self.inline_convert_bytes}")
        if self.rate_limit_per_s <= 0 or self.rate_burst < 1 or self.refusal_logs_per_s <= 0:
            raise ValueError("rate_limit_per_s, rate_burst and refusal_logs_per_s must be positive")


@dataclass(frozen=True)
class TopicRule:
    """One allow-listed topic: name as configured (relative or absolute), type, class and QoS."""

    topic: str
    type: str
    topic_class: TopicClass
    qos: QosName

    @property
    def drops_oldest(self) -> bool:
        """Video keeps only what is fresh; every other class is never dropped without a report."""
        return self.topic_class == "video"


class ConfigError(ValueError):
    pass


@dataclass(frozen=True)
class AllowLists:
    subscribe: tuple[TopicRule, ...] = ()  # ROS → clients
    publish: tuple[TopicRule, ...] = ()  # clients → ROS
    services: tuple[ServiceRule, ...] = ()  # clients call them
    actions: tuple[ActionRule, ...] = ()  # clients send goals to them

    def merged(self, other: AllowLists) -> AllowLists:
        """The union (bridge.yaml + the tools' interfaces). The same name twice must mean the same
        thing: a different type, class or QoS is a ConfigError; for calls the longer timeout wins
        (a tool that declares a long service keeps it)."""
        return AllowLists(
            _merge_topics(self.subscribe, other.subscribe, "subscribe"),
            _merge_topics(self.publish, other.publish, "publish"),
            _merge_calls(self.services, other.services, "services"),
            _merge_calls(self.actions, other.actions, "actions"),
        )


def _merge_topics(
    ours: tuple[TopicRule, ...], theirs: tuple[TopicRule, ...], section: str
) -> tuple[TopicRule, ...]:
    by_name = {rule.topic: rule for rule in ours}
    for rule in theirs:
        known = by_name.setdefault(rule.topic, rule)
        if known != rule:
            raise ConfigError(
                f"'{section}' lists {rule.topic!r} twice with different settings: {known} and {rule}"
            )
    return tuple(by_name.values())


_CallRule = TypeVar("_CallRule", ServiceRule, ActionRule)


def _merge_calls(
    ours: tuple[_CallRule, ...], theirs: tuple[_CallRule, ...], section: str
) -> tuple[_CallRule, ...]:
    by_name = {rule.name: rule for rule in ours}
    for rule in theirs:
        known = by_name.setdefault(rule.name, rule)
        if known.type != rule.type:
            raise ConfigError(f"'{section}' lists {rule.name!r} with two types: {known.type} and {rule.type}")
        if rule.timeout_s > known.timeout_s:
            by_name[rule.name] = rule
    return tuple(by_name.values())


def _default_class(type_name: str) -> TopicClass:
    short = type_name.rsplit("/", 1)[-1]
    if "Image" in short:
        return "video"
    if "Audio" in short:
        return "audio"
    return "text" if short == "String" else "state"


def _rule(entry: Any, section: str, index: int) -> TopicRule:
    where = f"{section}[{index}]"
    if not isinstance(entry, dict):
        raise ConfigError(f"{where}: expected a mapping with 'topic' and 'type'")
    unknown = set(entry) - {"topic", "type", "class", "qos"}
    if unknown:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)}")
    topic, type_name = entry.get("topic"), entry.get("type")
    if not isinstance(topic, str) or not topic or not isinstance(type_name, str):
        raise ConfigError(f"{where}: 'topic' and 'type' must be non-empty strings")
    try:
        normalized = normalize_type(type_name)
    except ValueError as error:
        raise ConfigError(f"{where}: {error}") from None
    topic_class = entry.get("class", _default_class(normalized))
    if topic_class not in TOPIC_CLASSES:
        raise ConfigError(f"{where}: class must be one of {TOPIC_CLASSES}, got {topic_class!r}")
    qos = entry.get("qos", "stream" if topic_class == "video" else "reliable")
    if qos not in QOS_NAMES:
        raise ConfigError(f"{where}: qos must be one of {QOS_NAMES}, got {qos!r}")
    return TopicRule(topic, normalized, topic_class, qos)


def _call_rule(entry: Any, section: str, index: int) -> tuple[str, str, float]:
    """(name, normalised type, timeout_s) of one `services:` or `actions:` entry."""
    where = f"{section}[{index}]"
    kind: InterfaceKind = "srv" if section == "services" else "action"
    if not isinstance(entry, dict):
        raise ConfigError(f"{where}: expected a mapping with 'name' and 'type'")
    unknown = set(entry) - {"name", "type", "timeout_s"}
    if unknown:
        raise ConfigError(f"{where}: unknown keys {sorted(unknown)} (expected name, type, timeout_s)")
    name, type_name = entry.get("name"), entry.get("type")
    if not isinstance(name, str) or not name or not isinstance(type_name, str):
        raise ConfigError(f"{where}: 'name' and 'type' must be non-empty strings")
    try:
        resolve_topic(name, "/")  # same rules as a topic name
        normalized = normalize_interface(type_name, kind)
    except ValueError as error:
        raise ConfigError(f"{where}: {error}") from None
    timeout = entry.get("timeout_s", 10.0)
    if (
        isinstance(timeout, bool)
        or not isinstance(timeout, (int, float))
        or not math.isfinite(timeout)
        or not 0 < timeout <= MAX_CALL_TIMEOUT_S
    ):
        raise ConfigError(
            f"{where}: timeout_s must be a number of seconds in (0, {MAX_CALL_TIMEOUT_S:g}], got {timeout!r}"
        )
    return name, normalized, float(timeout)


SECTIONS = ("subscribe", "publish", "services", "actions")


def _section(data: dict[str, Any], section: str) -> list[Any]:
    entries = data.get(section) or []
    if not isinstance(entries, list):
        raise ConfigError(f"'{section}' must be a list")
    return entries


def _no_duplicates(section: str, names: list[str]) -> None:
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise ConfigError(f"'{section}' lists {duplicates} more than once")


def parse_allow_lists(data: Any) -> AllowLists:
    if data is None:
        return AllowLists()
    if not isinstance(data, dict):
        raise ConfigError(
            "bridge config must be a mapping with 'subscribe', 'publish', 'services' or 'actions' lists"
        )
    unknown = set(data) - set(SECTIONS)
    if unknown:
        raise ConfigError(f"unknown top-level keys {sorted(unknown)} (expected {', '.join(SECTIONS)})")
    sections: dict[str, tuple[TopicRule, ...]] = {}
    for section in ("subscribe", "publish"):
        rules = tuple(_rule(entry, section, index) for index, entry in enumerate(_section(data, section)))
        _no_duplicates(section, [rule.topic for rule in rules])
        sections[section] = rules
    services = tuple(
        ServiceRule(*_call_rule(e, "services", i)) for i, e in enumerate(_section(data, "services"))
    )
    actions = tuple(ActionRule(*_call_rule(e, "actions", i)) for i, e in enumerate(_section(data, "actions")))
    _no_duplicates("services", [rule.name for rule in services])
    _no_duplicates("actions", [rule.name for rule in actions])
    return AllowLists(sections["subscribe"], sections["publish"], services, actions)


def load_allow_lists(path: Path) -> AllowLists:
    try:
        return parse_allow_lists(yaml.safe_load(path.read_text(encoding="utf-8")))
    except OSError as error:
        raise ConfigError(f"cannot read bridge config {path}: {error}") from None
    except yaml.YAMLError as error:
        raise ConfigError(f"bridge config {path} is not valid YAML: {error}") from None
