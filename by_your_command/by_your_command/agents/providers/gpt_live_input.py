"""GPT-Live's input as one continuous stream in real time (the session takes a microphone, not
utterances).

Our VAD forwards speech only (with its pre-roll), so between utterances nothing comes: the model
would not hear the user stop, nor time pass. `InputClock` says how much silence keeps the stream at
real time: none while an utterance is open (its audio comes at the microphone's pace; silence
spliced into speech would break words), and, between utterances, what the stream is behind the
clock. A pre-roll sent at once puts the stream ahead of the clock: the silence then waits until
the clock catches up, so the model always hears time as it passed, never faster.
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
        self._origin: float | None = None  # when the stream's first sample counts as played
        self._sent = 0  # samples appended (speech and silence)
        self.in_utterance = False

    @property
    def started(self) -> bool:
        return self._origin is not None

    def start(self, now: float) -> None:
        if self._origin is None:
            self._origin = now

    def sent(self, samples: int, now: float) -> None:
        self.start(now)
        self._sent += samples

    def silence_due(self, now: float) -> SilencePlan:
        """The silence to append now; after a stall longer than max_catch_up, the rest is skipped
        (the clock moves on) rather than sent as a burst the model would take as a long pause."""
        if self._origin is None or self.in_utterance:
            return SilencePlan(0, 0)
        behind = round((now - self._origin) * self.sample_rate) - self._sent
        if behind <= 0:
            return SilencePlan(0, 0)
        if behind > self.max_catch_up:
            skipped = behind - self.max_catch_up
            self._origin += skipped / self.sample_rate
            return SilencePlan(self.max_catch_up, skipped)
        return SilencePlan(behind, 0)
