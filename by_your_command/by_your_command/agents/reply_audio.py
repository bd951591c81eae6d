"""One spoken reply as the player sees it: streams published, audio kept, playing or not.

The player can only cut a stream (`Interruption`), never pause it. So the agent keeps every reply's
audio, and a barge-in that proves false resumes by publishing what was not heard (from `played_ms`
on) as a new stream. Whether the reply is still audible comes from `playback_status`; before the
player has reported it, from how much audio was published and when (so a silent player cannot keep
the agent "busy" forever).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from by_your_command.agents.inputs import PlaybackStatus

MAX_KEPT_S = 600.0  # audio kept per reply for resuming; beyond it a resume replays what was kept
PLAYBACK_GRACE_S = 2.0  # no status from the player: assume it plays this long after the audio's length
STATUS_STALE_S = 2.0  # the player reports at 10 Hz while speaking; older news may be from a dead player
RESUME_CHUNK_S = 1.0  # a resumed remainder is published in pieces this long


@dataclass
class ReplyAudio:
    response_id: str
    item_id: str
    sample_rate: int
    stream_id: str
    session: int  # serial of the provider session that produced it (only that one can truncate it)
    turn: int  # number of the user turn it answers
    pcm: bytearray = field(default_factory=bytearray)  # everything received for this reply
    stream_start: int = 0  # byte offset in pcm where the current stream starts
    stream_started_at: float | None = None  # when its first chunk was published
    status: PlaybackStatus | None = None  # the player's latest report on the current stream
    status_at: float = 0.0
    generation_done: bool = False
    ended_stream: bool = False  # end_of_stream published for the current stream
    cut: bool = False  # a confirmed barge-in cut it: nothing more is published
    dropped_bytes: int = 0  # received beyond MAX_KEPT_S (published, not kept)

    @property
    def bytes_per_s(self) -> int:
        return 2 * self.sample_rate

    def keep(self, pcm: bytes) -> None:
        room = int(MAX_KEPT_S * self.bytes_per_s) - len(self.pcm)
        self.pcm += pcm[: max(0, room)]
        self.dropped_bytes += max(0, len(pcm) - max(0, room))

    def stream_seconds(self) -> float:
        return (len(self.pcm) - self.stream_start) / self.bytes_per_s

    def played_ms(self) -> int:
        return 0 if self.status is None else self.status.played_ms

    def playing_until(self) -> float | None:
        """Until when the reply may be audible (or queued at the player), on what we know now."""
        if self.stream_started_at is None:
            return None
        status = self.status
        if status is not None:
            if status.finished or status.interrupted:
                return None
            if status.speaking or status.starved or status.queued_ms > 0:
                return max(self.status_at + STATUS_STALE_S, self.estimated_end())
        return self.estimated_end()

    def is_playing(self, now: float) -> bool:
        until = self.playing_until()
        return until is not None and now < until

    def estimated_end(self) -> float:
        started = self.stream_started_at if self.stream_started_at is not None else 0.0
        return started + self.stream_seconds() + PLAYBACK_GRACE_S

    def remainder(self) -> bytes:
        """The audio of the current stream the player did not play (from played_ms on)."""
        offset = self.stream_start + int(self.played_ms() * self.sample_rate / 1000) * 2
        return bytes(self.pcm[min(offset, len(self.pcm)) :])

    def restart_stream(self, stream_id: str) -> bytes:
        """Start a new stream at the unplayed remainder; returns that remainder."""
        rest = self.remainder()
        self.stream_start = len(self.pcm) - len(rest)
        self.stream_id = stream_id
        self.stream_started_at = None
        self.status = None
        self.status_at = 0.0
        self.ended_stream = False
        return rest


def pieces(pcm: bytes, sample_rate: int, seconds: float = RESUME_CHUNK_S) -> list[bytes]:
    size = max(2, int(seconds * sample_rate) * 2)
    return [pcm[start : start + size] for start in range(0, len(pcm), size)]
