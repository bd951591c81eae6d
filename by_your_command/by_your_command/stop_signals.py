"""What a stop signal means to a node or an agent: the first stops in order, a second one exits now.

One Ctrl-C can arrive twice: the terminal sends SIGINT to its whole foreground process group, and
`ros2 launch` (non-interactive, e.g. stdin not a terminal) or another supervisor also sends its own
SIGINT to each child a few milliseconds later. Taking that copy as "the user insists" skipped every
process's orderly shutdown, so a SIGINT repeated within DUPLICATE_WINDOW_S of the first is the same
stop. Any other second signal (a later Ctrl-C, launch's SIGTERM escalation) still exits at once.
"""

from __future__ import annotations

import enum
import signal
import time
from collections.abc import Callable

DUPLICATE_WINDOW_S = 1.0  # launch forwards within ms; a person pressing again because it hangs waits longer

# Exit statuses of a process stopped on request: run_node and agents exit 0, a plain process dies
# of the signal (negative: subprocess's convention for "killed by").
CLEAN_STOP_STATUSES = (0, -signal.SIGTERM, -signal.SIGINT)


class StopVerdict(enum.Enum):
    STOP = "stop"  # the first request: stop in order
    SAME_STOP = "same stop"  # a copy of the first Ctrl-C: keep stopping in order
    EXIT_NOW = "exit now"  # a second request: give up the orderly stop


class StopRequests:
    """Judges each SIGINT/SIGTERM a process receives (call from its signal handler)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._first: tuple[int, float] | None = None  # (signal, when)

    @property
    def stopping(self) -> bool:
        return self._first is not None

    def receive(self, signum: int) -> StopVerdict:
        now = self._clock()
        if self._first is None:
            self._first = (signum, now)
            return StopVerdict.STOP
        first_signum, first_at = self._first
        if signum == first_signum == signal.SIGINT and now - first_at < DUPLICATE_WINDOW_S:
            return StopVerdict.SAME_STOP
        return StopVerdict.EXIT_NOW


def stopped_on_request(status: int) -> bool:
    return status in CLEAN_STOP_STATUSES
