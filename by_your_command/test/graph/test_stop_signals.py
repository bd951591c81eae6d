"""What a node's or an agent's signal handler does with each stop signal (stop_signals.py)."""

from __future__ import annotations

import signal

import pytest

from by_your_command.stop_signals import DUPLICATE_WINDOW_S, StopRequests, StopVerdict


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.mark.unit
def test_one_ctrl_c_delivered_twice_is_one_stop() -> None:
    """The terminal's SIGINT and launch's copy of it a few ms later."""
    clock = Clock()
    requests = StopRequests(clock)
    assert requests.receive(signal.SIGINT) is StopVerdict.STOP
    clock.now += 0.01
    assert requests.receive(signal.SIGINT) is StopVerdict.SAME_STOP
    assert requests.stopping


@pytest.mark.unit
def test_a_later_ctrl_c_exits_now() -> None:
    clock = Clock()
    requests = StopRequests(clock)
    requests.receive(signal.SIGINT)
    clock.now += DUPLICATE_WINDOW_S
    assert requests.receive(signal.SIGINT) is StopVerdict.EXIT_NOW


@pytest.mark.unit
@pytest.mark.parametrize(
    "first, second",
    [(signal.SIGINT, signal.SIGTERM), (signal.SIGTERM, signal.SIGTERM), (signal.SIGTERM, signal.SIGINT)],
)
def test_any_other_second_signal_exits_now(first: int, second: int) -> None:
    """Launch escalates with SIGTERM; `byc up` stops with one SIGTERM: a second one is meant."""
    clock = Clock()
    requests = StopRequests(clock)
    assert not requests.stopping
    assert requests.receive(first) is StopVerdict.STOP
    assert requests.receive(second) is StopVerdict.EXIT_NOW
