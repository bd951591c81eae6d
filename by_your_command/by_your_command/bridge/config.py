"""Bridge settings: ROS parameters (one dataclass, the one place defaults live) and YAML allow-lists."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from by_your_command.bridge.protocol import normalize_type

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


@dataclass(frozen=True)
class AllowLists:
    subscribe: tuple[TopicRule, ...] = ()  # ROS → clients
    publish: tuple[TopicRule, ...] = ()  # clients → ROS


class ConfigError(ValueError):
    pass


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


def parse_allow_lists(data: Any) -> AllowLists:
    if data is None:
        return AllowLists()
    if not isinstance(data, dict):
        raise ConfigError("bridge config must be a mapping with 'subscribe' and/or 'publish' lists")
    unknown = set(data) - {"subscribe", "publish"}
    if unknown:
        raise ConfigError(f"unknown top-level keys {sorted(unknown)} (expected subscribe, publish)")
    sections: dict[str, tuple[TopicRule, ...]] = {}
    for section in ("subscribe", "publish"):
        entries = data.get(section) or []
        if not isinstance(entries, list):
            raise ConfigError(f"'{section}' must be a list")
        rules = tuple(_rule(entry, section, index) for index, entry in enumerate(entries))
        names = [rule.topic for rule in rules]
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise ConfigError(f"'{section}' lists {duplicates} more than once")
        sections[section] = rules
    return AllowLists(sections["subscribe"], sections["publish"])


def load_allow_lists(path: Path) -> AllowLists:
    try:
        return parse_allow_lists(yaml.safe_load(path.read_text(encoding="utf-8")))
    except OSError as error:
        raise ConfigError(f"cannot read bridge config {path}: {error}") from None
    except yaml.YAMLError as error:
        raise ConfigError(f"bridge config {path} is not valid YAML: {error}") from None
