"""The reconnect backoff (net/backoff.py `backoff_s`, used by agents and the bridge client): capped
exponential with equal jitter, so agents that lost the same provider or bridge at once do not
reconnect in lockstep."""

from __future__ import annotations

import random

import pytest

from by_your_command.net.backoff import backoff_s

pytestmark = [pytest.mark.unit]


def test_each_delay_is_between_half_the_cap_and_the_cap() -> None:
    lowest, highest = (lambda low, _high: low), (lambda _low, high: high)
    for attempt, cap in [(1, 0.5), (2, 1.0), (3, 2.0), (4, 4.0), (5, 5.0), (60, 5.0)]:
        assert backoff_s(attempt, 0.5, 5.0, lowest) == cap / 2
        assert backoff_s(attempt, 0.5, 5.0, highest) == cap


def test_delays_grow_exponentially_to_their_cap_with_jitter() -> None:
    rng = random.Random(7)
    for attempt in range(1, 41):
        cap = min(5.0, 0.1 * 2 ** (attempt - 1))
        draws = [backoff_s(attempt, 0.1, 5.0, rng.uniform) for _ in range(20)]
        assert all(cap / 2 <= draw <= cap for draw in draws)
        assert len(set(draws)) > 1  # jittered at every step, the capped ones too


def test_agents_failing_together_spread_their_retries() -> None:
    delays = {backoff_s(3, 0.5, 5.0, random.Random(seed).uniform) for seed in range(20)}
    assert len(delays) == 20  # not one instant for every agent
    assert all(1.0 <= delay <= 2.0 for delay in delays)
    assert 0.0 < backoff_s(1, 0.5, 5.0)  # the default source: random, never an instant retry
