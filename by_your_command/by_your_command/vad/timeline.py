"""Whether an audio block continues the stream: tells a gap (dropped blocks) from stamp jitter."""

from __future__ import annotations

from dataclasses import dataclass

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class Discontinuity:
    reason: str  # "gap" (later than expected), "jump back" (earlier) or "rate change"
    offset_ns: int  # stamp minus where the stream was expected to continue


@dataclass(frozen=True)
class Placement:
    stamp_ns: int  # time of the block's first sample, as the pipeline should use it
    discontinuity: Discontinuity | None  # set when the block starts a new stream


class StreamTimeline:
    """Expects each block to start where the previous one ended (its stamp plus its samples).

    The expectation is re-anchored on every stamped block, so a sample clock that drifts from
    the system clock never adds up to a false gap. An unstamped block is taken to continue the
    stream; only the first block of a stream needs a time (its arrival time will do).
    """

    def __init__(self, tolerance_ns: int) -> None:
        self._tolerance = tolerance_ns
        self._expected_ns: int | None = None
        self._rate = 0

    @property
    def running(self) -> bool:
        return self._expected_ns is not None

    def place(self, stamp_ns: int, stamped: bool, samples: int, sample_rate: int) -> Placement:
        discontinuity = None
        if self._expected_ns is not None:
            offset = stamp_ns - self._expected_ns
            if sample_rate != self._rate:
                discontinuity = Discontinuity("rate change", offset)
            elif not stamped:
                stamp_ns = self._expected_ns
            elif offset > self._tolerance:
                discontinuity = Discontinuity("gap", offset)
            elif offset < -self._tolerance:
                discontinuity = Discontinuity("jump back", offset)
        self._rate = sample_rate
        self._expected_ns = stamp_ns + samples * NS_PER_S // sample_rate
        return Placement(stamp_ns, discontinuity)

    def reset(self) -> None:
        """The stream stopped (sleep, mute, timeout): the next block starts a new one."""
        self._expected_ns = None
