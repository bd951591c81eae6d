"""Half duplex: audio heard while the robot spoke (and a tail after) is not the user. Used by the
VAD (`echo_gate`, the profiles' gate mode) and by echo_suppressor's `gate` mode.

A block is judged by when it was captured (its stamp), not when it arrived: a block that waited
in a queue while `assistant_speaking` changed still belongs to the moment it was heard. Stamps
that are not on this clock (unstamped blocks, a file played faster than real time) are judged by
their arrival instead.
"""

from __future__ import annotations

from collections import deque

# A stamp further than this from the arrival time is on another clock (or the block waited longer
# than the VAD's input queue can hold: 64 blocks of 64 ms).
TRUSTED_STAMP_NS = 5_000_000_000
NS_PER_S = 1_000_000_000
KEPT_SPELLS = 16  # speaking spells remembered: blocks are judged within seconds of their capture


class EchoGate:
    def __init__(self, tail_ms: int) -> None:
        self._tail_ns = tail_ms * 1_000_000
        self._spells: deque[tuple[int, int | None]] = deque(maxlen=KEPT_SPELLS)  # (start, end or None)

    @property
    def speaking(self) -> bool:
        return bool(self._spells) and self._spells[-1][1] is None

    def set_speaking(self, speaking: bool, now_ns: int) -> bool:
        """Record a change of assistant_speaking; True when the robot starts to speak."""
        if speaking == self.speaking:
            return False
        if speaking:
            self._spells.append((now_ns, None))
        else:
            start, _ = self._spells.pop()
            self._spells.append((start, now_ns))
        return speaking

    def admits(self, start_ns: int, samples: int, sample_rate: int, now_ns: int) -> bool:
        """Whether a block of `samples` (all channels) captured from `start_ns` on may hold the
        user, not the robot. The rate is not checked here (the caller does, for what it admits)."""
        start_ns, end_ns = captured(start_ns, samples, sample_rate, now_ns)
        for spell_start, spell_end in self._spells:
            if spell_end is None:
                if end_ns > spell_start:
                    return False
            elif start_ns < spell_end + self._tail_ns and end_ns > spell_start:
                return False
        return True


def captured(start_ns: int, samples: int, sample_rate: int, now_ns: int) -> tuple[int, int]:
    """When a block of `samples` (all channels) stamped `start_ns` was heard, as (start, end) on
    the clock of `now_ns`: its arrival, for a stamp that is not on that clock."""
    end_ns = start_ns + samples * NS_PER_S // max(sample_rate, 1)
    if not start_ns or abs(now_ns - end_ns) > TRUSTED_STAMP_NS:
        start_ns = end_ns = now_ns
    return start_ns, max(end_ns, start_ns + 1)
