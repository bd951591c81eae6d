"""Monitor settings: the bridge node's ROS parameters for it, and config/monitor.yaml (prices, page).

The YAML is read once at startup and checked strictly: unknown keys, wrong types and negative prices
are errors naming the key, so a typo never silently prices a provider at zero.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from by_your_command.monitor.cost import Prices


class MonitorConfigError(ValueError):
    pass


@dataclass(frozen=True)
class MonitorParams:
    """ros_ai_bridge parameters of the monitor (the defaults live here only)."""

    monitor_page: bool = field(
        default=True, metadata={"help": "serve the monitor page on the bridge's port (same token rules)"}
    )
    monitor_config_path: str = field(
        default="", metadata={"help": "prices and page settings; empty = the installed config/monitor.yaml"}
    )
    metrics_topic: str = field(default="agent_metrics", metadata={"help": "the agents' per-turn records"})
    summary_topic: str = field(
        default="agent_summary", metadata={"help": "latched JSON summary per agent and provider; '' = off"}
    )
    summary_period_s: float = field(
        default=1.0,
        metadata={"help": "how often a changed summary is published (and /diagnostics gets agents)"},
    )

    def __post_init__(self) -> None:
        if not self.summary_period_s > 0:
            raise ValueError(f"summary_period_s must be > 0, got {self.summary_period_s}")
        if not self.metrics_topic:
            raise ValueError("metrics_topic must not be empty")


@dataclass(frozen=True)
class PageSettings:
    camera_interval_ms: int = 500  # throttle_rate of the page's camera_forwarded subscription
    transcript_lines: int = 300
    latency_turns: int = 50  # turns in the median latency (summary and page)

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 100_000:
                raise ValueError(f"{item.name}: an integer 1..100000, got {value!r}")


@dataclass(frozen=True)
class MonitorConfig:
    currency: str = "USD"
    prices: Mapping[str, Prices] = field(default_factory=dict)  # by Provider.name
    page: PageSettings = field(default_factory=PageSettings)

    def for_page(self) -> dict[str, Any]:
        """What the page is told (served as JSON): nothing secret, nothing it could not show."""
        return {
            "currency": self.currency,
            "prices": {name: vars(prices) for name, prices in sorted(self.prices.items())},
            "page": vars(self.page),
        }


def parse_monitor_config(data: Any) -> MonitorConfig:
    if data is None:
        return MonitorConfig()
    if not isinstance(data, dict):
        raise MonitorConfigError("monitor config: expected a mapping at the top level")
    _no_unknown_keys(data, {"currency", "prices", "page"}, "")
    currency = data.get("currency", MonitorConfig.currency)
    if not isinstance(currency, str) or not 1 <= len(currency) <= 8:
        raise MonitorConfigError(f"currency: a short text such as USD, got {currency!r}")
    prices_data = data.get("prices") or {}
    if not isinstance(prices_data, dict):
        raise MonitorConfigError("prices: expected a mapping of provider name to prices")
    prices = {}
    for provider, entry in prices_data.items():
        if not isinstance(provider, str) or not provider:
            raise MonitorConfigError(f"prices: provider names are text, got {provider!r}")
        prices[provider] = _build(Prices, entry, f"prices.{provider}")
    page = _build(PageSettings, data.get("page"), "page")
    return MonitorConfig(currency, prices, page)


def load_monitor_config(path: Path) -> MonitorConfig:
    try:
        return parse_monitor_config(yaml.safe_load(path.read_text(encoding="utf-8")))
    except OSError as error:
        raise MonitorConfigError(f"cannot read monitor config {path}: {error}") from None
    except yaml.YAMLError as error:
        raise MonitorConfigError(f"monitor config {path} is not valid YAML: {error}") from None
    except MonitorConfigError as error:
        raise MonitorConfigError(f"monitor config {path}: {error}") from None


def _no_unknown_keys(data: dict[Any, Any], known: set[str], where: str) -> None:
    unknown = sorted(str(key) for key in data if key not in known)
    if unknown:
        raise MonitorConfigError(f"{where or 'top level'}: unknown key(s) {unknown} (known: {sorted(known)})")


def _build(cls: Any, entry: Any, where: str) -> Any:
    if entry is None:
        return cls()
    if not isinstance(entry, dict):
        raise MonitorConfigError(f"{where}: expected a mapping")
    _no_unknown_keys(entry, {item.name for item in fields(cls)}, where)
    try:
        return cls(**entry)
    except ValueError as error:
        raise MonitorConfigError(f"{where}.{error}") from None
