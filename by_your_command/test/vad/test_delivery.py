"""DeliveryCheck: utterances no live subscriber acknowledged are judged lost, once, and only after
the publisher has been quiet for the confirmation window (acknowledgements come with heartbeats)."""

from __future__ import annotations

import pytest
from rclpy.duration import Duration

from by_your_command.nodes._delivery import MAX_PENDING, DeliveryCheck

pytestmark = pytest.mark.unit


class FakePublisher:
    def __init__(self) -> None:
        self.acked = False
        self.subscribers = 1
        self.timeouts: list[Duration] = []

    def get_subscription_count(self) -> int:
        return self.subscribers

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


def test_an_utterance_whose_subscriber_left_before_acknowledging_is_judged_at_once() -> None:
    # A killed bridge is unmatched when its lease runs out; from then on "all acknowledged" speaks
    # only for the subscribers still there, and must not clear what the one that left never got.
    publisher, clock = FakePublisher(), Clock()
    publisher.subscribers = 2
    check = DeliveryCheck(publisher, confirm_s=5.0, clock=clock)
    check.published(utterance_id=1)
    publisher.subscribers, publisher.acked = 1, True
    check.published(utterance_id=2)  # ended after the departure: the one left acknowledged it
    assert check.unacknowledged() == [1]
    assert check.pending == 0


def test_a_full_pending_list_judges_its_oldest_instead_of_dropping_them() -> None:
    publisher, clock = FakePublisher(), Clock()
    check = DeliveryCheck(publisher, confirm_s=5.0, clock=clock)
    for utterance in range(MAX_PENDING + 2):
        check.published(utterance_id=utterance)
    assert check.unacknowledged() == [0, 1]  # the rest stay pending until the window passes
    assert check.pending == MAX_PENDING
