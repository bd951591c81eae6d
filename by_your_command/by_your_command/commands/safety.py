"""The last check before a command reaches an actuator: allow-list and per-command rate limit.

`stop` is special: it is always allowed and never rate-limited, whatever the configuration says.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from by_your_command.commands.grammar import Command

ALWAYS_ALLOWED = "stop"


@dataclass(frozen=True)
class SafetyConfig:
    allowed: frozenset[str] | None = None  # command bases; None = the whole vocabulary
    min_interval_s: float = 1.0  # the same command again within this time is refused; 0 = off

    def __post_init__(self) -> None:
        if self.min_interval_s < 0:
            raise ValueError(f"min_interval_s must be >= 0, got {self.min_interval_s}")


def allow_list(bases: Iterable[str]) -> frozenset[str] | None:
    """An allow-list from configuration: empty means no restriction."""
    cleaned = frozenset(base.strip().lower() for base in bases if base.strip())
    return cleaned or None


class SafetyGate:
    def __init__(self, config: SafetyConfig) -> None:
        self.config = config
        self._last_accepted: dict[str, float] = {}

    def check(self, command: Command, now: float) -> str:
        """'' when the command may go out (and it is then recorded), else the reason it may not."""
        if command.base == ALWAYS_ALLOWED:
            return ""
        allowed = self.config.allowed
        if allowed is not None and command.base not in allowed:
            return f"{command.base!r} is not in the allow-list"
        interval = self.config.min_interval_s
        last = self._last_accepted.get(command.text)
        if interval > 0 and last is not None and now - last < interval:
            return f"rate limited: {command.text!r} repeated within {interval:g} s"
        self._last_accepted[command.text] = now
        return ""
