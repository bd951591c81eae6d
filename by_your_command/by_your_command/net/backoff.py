"""The wait before reconnecting: to a provider (agents) and to the bridge (the bridge client)."""

from __future__ import annotations

import random
from collections.abc import Callable

_JITTER = random.Random()  # reconnect timing only: no need for a cryptographic source


def backoff_s(
    attempt: int, initial_s: float, max_s: float, uniform: Callable[[float, float], float] = _JITTER.uniform
) -> float:
    """Delay before reconnect attempt `attempt` (1, 2, …): capped exponential with equal jitter, a
    random point in [cap / 2, cap]. Jitter keeps agents that lost one provider (or one network)
    together from reconnecting in lockstep; the fixed half keeps a floor, so a retry never comes
    at once after a failure (full jitter may pick ~0). `uniform` is injectable for tests."""
    cap = float(min(max_s, initial_s * 2.0 ** min(max(attempt - 1, 0), 30)))
    return uniform(cap / 2, cap)
