"""One spoken reply as the player sees it: stream published, audio received, playing or not.

A barge-in pauses the reply's stream at the player; a false one resumes the same stream, so the
player's played_ms runs on over the whole reply and a later real barge-in truncates at what the
user heard of all of it. Whether the reply is still audible comes from `playback_status`; before
the player has reported it, from how much audio was published and when (so a silent player cannot
keep the agent "busy" forever).
"""

from __future__ import annotations

from dataclasses import dataclass

from by_your_command.agents.inputs import PlaybackStatus

PLAYBACK_GRACE_S = 2.0  # no status from the player: assume it plays this long after the audio's length
STATUS_STALE_S = 2.0  # the player reports at 10 Hz while speaking; older news may be from a dead player


@dataclass
class ReplyAudio:
    response_id: str
    item_id: str
    sample_rate: int
    stream_id: str
    session: int  # serial of the provider session that produced it (only that one can truncate it)
    turn: int  # number of the user turn it answers
    received_bytes: int = 0  # audio received for this reply (all of it was published)
    stream_started_at: float | None = None  # when its first chunk was published
    status: PlaybackStatus | None = None  # the player's latest report on the stream
    status_at: float = 0.0
    generation_done: bool = False
    ended_stream: bool = False  # end_of_stream published
    cut: bool = False  # a confirmed barge-in (or a safety stop) cut it: nothing more is published

    @property
    def bytes_per_s(self) -> int:
        return 2 * self.sample_rate

    def received_ms(self) -> int:
        return self.received_bytes * 1000 // self.bytes_per_s

    def heard_ms(self, stopped_at: float) -> int:
        """What the listener heard of this reply when the player stopped it at `stopped_at` (our
        clock), clamped to the audio received: the point to truncate the model's memory at."""
        status = self.status
        if status is None:
            started = self.stream_started_at if self.stream_started_at is not None else stopped_at
            heard = 1000 * max(0.0, stopped_at - started)  # at best it played from its first chunk on
        elif status.paused or status.interrupted or status.finished or not status.speaking:
            heard = status.played_ms
        else:  # the latest report is from before the stop: it played on until then
            heard = status.played_ms + 1000 * max(0.0, stopped_at - self.status_at)
        return int(min(heard, self.received_ms()))

    def playing_until(self) -> float | None:
        """Until when the reply may be audible (or queued, or paused, at the player), on what we know now."""
        if self.stream_started_at is None:
            return None
        status = self.status
        if status is not None:
            if status.finished or status.interrupted:
                return None
            if status.speaking or status.paused or status.starved or status.queued_ms > 0:
                return max(self.status_at + STATUS_STALE_S, self.estimated_end())
        return self.estimated_end()

    def is_playing(self, now: float) -> bool:
        until = self.playing_until()
        return until is not None and now < until

    def estimated_end(self) -> float:
        started = self.stream_started_at if self.stream_started_at is not None else 0.0
        return started + self.received_bytes / self.bytes_per_s + PLAYBACK_GRACE_S
