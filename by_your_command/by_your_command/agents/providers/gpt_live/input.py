"""GPT-Live's input as one continuous stream in real time (the session takes a microphone, not
utterances).

Our VAD forwards speech only (with its pre-roll), so between utterances nothing comes: the model
would not hear the user stop, nor time pass. `InputClock` says how much silence keeps the stream
going: none while an utterance is open (its audio comes at the microphone's pace; silence spliced
into speech would break words), and, between utterances, the time since the stream last covered
real time. Live audio arrives when it has been said, so a speech chunk covers time up to its
arrival; the silence after an utterance starts there, with no gap and no overlap.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SilencePlan:
    samples: int  # silence to append now (0: nothing)
    skipped: int  # samples the stream fell behind by more than max_catch_up (a stalled loop)


class InputClock:
    def __init__(self, sample_rate: int, max_catch_up_s: float) -> None:
        self.sample_rate = sample_rate
        self.max_catch_up = int(sample_rate * max_catch_up_s)
        self._covered: float | None = None  # real time the stream has covered up to
        self.in_utterance = False

    def start(self, now: float) -> None:
        if self._covered is None:
            self._covered = now

    def speech_sent(self, now: float) -> None:
        """Speech appended: it was said by now (a pre-roll sent at once is older, never newer)."""
        self._covered = now

    def silence_due(self, now: float) -> SilencePlan:
        """The silence to append now (the stream then covers up to `now`); after a stall longer
        than max_catch_up the rest is skipped rather than sent as one long pause at once."""
        if self._covered is None or self.in_utterance:
            return SilencePlan(0, 0)
        behind = round((now - self._covered) * self.sample_rate)
        if behind <= 0:
            return SilencePlan(0, 0)
        self._covered = now
        if behind > self.max_catch_up:
            return SilencePlan(self.max_catch_up, behind - self.max_catch_up)
        return SilencePlan(behind, 0)
