"""DeliveryCheck: utterances no live subscriber acknowledged are judged lost, once, and only after
the publisher has been quiet for the confirmation window (acknowledgements come with heartbeats)."""

from __future__ import annotations

import pytest
from rclpy.duration import Duration

from by_your_command.nodes._delivery import DeliveryCheck

pytestmark = pytest.mark.unit


class FakePublisher:
    def __init__(self) -> None:
        self.acked = False
        self.timeouts: list[Duration] = []

    def wait_for_all_acked(self, timeout: Duration) -> bool:
        self.timeouts.append(timeout)
        return self.acked


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_an_acknowledged_utterance_is_never_reported() -> None:
    publisher, clock = FakePublisher(), Clock()
    check = DeliveryCheck(publisher, confirm_s=5.0, clock=clock)
    check.published()
    check.published(utterance_id=7)
    clock.now += 2.0
    assert check.unacknowledged() == []
    publisher.acked = True  # the heartbeat came, the subscriber acknowledged
    assert check.unacknowledged() == [] and check.pending == 0
    publisher.acked = False
    clock.now += 60.0
    assert check.unacknowledged() == []  # nothing pending: nothing to judge
    assert all(t.nanoseconds == 0 for t in publisher.timeouts)  # never blocks (it holds the GIL)


def test_unacknowledged_utterances_are_lost_after_the_publisher_was_quiet_for_the_window() -> None:
    publisher, clock = FakePublisher(), Clock()
    check = DeliveryCheck(publisher, confirm_s=5.0, clock=clock)
    check.published(utterance_id=1)
    clock.now += 4.0
    check.published()  # the next utterance's chunks: the window restarts from the last publish
    check.published(utterance_id=2)
    clock.now += 4.9
    assert check.unacknowledged() == []
    clock.now += 0.2
    assert check.unacknowledged() == [1, 2]
    assert check.unacknowledged() == []  # each reported once
