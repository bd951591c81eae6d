"""Which published utterances no live subscriber acknowledged (a crashed bridge, say).

A subscriber process that dies without closing (SIGKILL, OOM, power) stays "matched" until its DDS
lease expires (about 20 s with Fast DDS defaults), and DDS drops what is published to it without a
word. A reliable reader acknowledges what it received; a dead one never does. So after an
utterance's end marker, the publisher is asked whether every matched reliable subscriber
acknowledged everything published so far. Acknowledgements come with the writer's heartbeats (up to
3 s apart with Fast DDS), and only cover what was published before them: judgement waits until
`confirm_s` after the last publish, and a single "all acknowledged" clears every pending utterance.

`Publisher.wait_for_all_acked` holds the GIL while it waits, so it is only ever called with a zero
timeout (a poll costs ~0.1 ms), from the node's timer.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.duration import Duration

_NOW = Duration(nanoseconds=0)
MAX_PENDING = 256  # utterances awaiting acknowledgement; older ones are judged at once


class DeliveryCheck:
    def __init__(self, publisher: Any, confirm_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self._publisher = publisher
        self._confirm_s = confirm_s
        self._clock = clock
        self._pending: list[tuple[int, int]] = []  # (utterance id, subscribers when it ended)
        self._judged: list[int] = []  # pushed out of a full pending list: not acknowledged in time
        self._last_publish = 0.0

    @property
    def pending(self) -> int:
        return len(self._pending)

    def published(self, utterance_id: int | None = None) -> None:
        """Something was just published; `utterance_id` when it was an utterance's end marker."""
        self._last_publish = self._clock()
        if utterance_id is not None:
            self._pending.append((utterance_id, self._publisher.get_subscription_count()))
            while len(self._pending) > MAX_PENDING:
                self._judged.append(self._pending.pop(0)[0])

    def unacknowledged(self) -> list[int]:
        """The pending utterances now judged lost (each returned once); [] while undecided."""
        lost, self._judged = self._judged, []
        if not self._pending:
            return lost
        # A subscriber that left (its lease ran out, or it stopped) took its acknowledgements with
        # it: "all acknowledged" would then speak only for those still there.
        count = self._publisher.get_subscription_count()
        lost += [utterance for utterance, subscribers in self._pending if subscribers > count]
        self._pending = [(u, n) for u, n in self._pending if n <= count]
        if self._pending and self._publisher.wait_for_all_acked(_NOW):
            self._pending.clear()
        elif self._clock() - self._last_publish >= self._confirm_s:
            lost += [utterance for utterance, _ in self._pending]
            self._pending.clear()
        return lost
