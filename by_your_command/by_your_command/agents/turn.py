"""One user turn (an utterance or a typed text) from its first chunk to the end of its reply.

The turn keeps its own audio (at the provider's rate) until the reply starts, so a session that
fails before answering can be replaced and the turn replayed whole: nothing the user said is lost
to a reconnect. Audio beyond `keep_limit_bytes` makes the turn non-replayable (reported if needed).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from by_your_command.agents.events import Usage
from by_your_command.agents.provider import ToolResult
from by_your_command.audio.pcm import StreamResampler


@dataclass
class Turn:
    number: int
    kind: str  # "voice" | "text" | "tool" (results of robot actions, docs/tools.md)
    started_at: float
    keep_limit_bytes: int
    utterance_id: int | None = None
    text: str = ""
    resampler: StreamResampler | None = None
    next_sequence: int = 0
    received_ms: float = 0.0  # user audio received (at its own rate)
    unvoiced_ms: float = 0.0  # of it, what the VAD did not judge speech (pre-roll, pauses)
    pre_roll_ms: float | None = None  # of it, what came before the VAD's onset (None: no speech yet)
    last_chunk_at: float = 0.0
    frame_since: float = float("-inf")  # frames that arrived before this show an earlier question
    audio: bytearray = field(default_factory=bytearray)  # at the provider's input rate
    replayable: bool = True
    held: bool = False  # a pending barge-in holds the audio until the speech proves real
    # Spoken while an earlier turn waited for its commit: the provider has one input buffer, so
    # this turn's audio goes only when it is committed (else the earlier commit would take it).
    deferred: bool = False
    ended_at: float | None = None  # end marker (or text) received: the moment latency is measured from
    committed: bool = False
    reply_started: bool = False
    first_audio_at: float | None = None
    tool_calls_open: set[str] = field(default_factory=set)
    tool_responses: set[str] = field(default_factory=set)  # responses that called tools: never the last
    # kind "tool": results of robot actions that ended after their own turn, for this session
    tool_results: tuple[ToolResult, ...] = ()
    tool_session: int = 0
    usage: Usage = field(default_factory=Usage)

    @property
    def ended(self) -> bool:
        return self.ended_at is not None

    @property
    def voiced_ms(self) -> float:
        """Speech heard from the VAD's onset on (all of it, from a VAD that does not say)."""
        return max(0.0, self.received_ms - self.unvoiced_ms)

    def audio_from_onset(self, lead_ms: float) -> bytes:
        """The audio kept, from `lead_ms` before the VAD's onset on (all of it while no onset)."""
        assert self.resampler is not None
        skipped_ms = max(0.0, (self.pre_roll_ms or 0.0) - lead_ms)
        return bytes(self.audio[2 * int(skipped_ms * self.resampler.to_rate / 1000) :])

    def add_audio(self, pcm: bytes) -> None:
        if len(self.audio) + len(pcm) > self.keep_limit_bytes:
            self.replayable = False
            return
        self.audio += pcm

    def resample(self, pcm: bytes, sample_rate: int, end: bool, unvoiced_samples: int = 0) -> bytes:
        """Our VAD's audio at the provider's rate (the resampler was made for this turn)."""
        assert self.resampler is not None
        samples = np.frombuffer(pcm, dtype="<i2")
        self.received_ms += 1000.0 * len(samples) / sample_rate
        # the VAD's running count; never more than was received (a hostile publisher)
        self.unvoiced_ms = min(
            max(self.unvoiced_ms, 1000.0 * unvoiced_samples / sample_rate), self.received_ms
        )
        if self.pre_roll_ms is None and self.unvoiced_ms < self.received_ms:
            # the first chunk with speech: what is not speech is the pre-roll (and a pause after the onset)
            self.pre_roll_ms = self.unvoiced_ms
        out = self.resampler.push(samples)
        if end:
            out = np.concatenate([out, self.resampler.flush()])
        return out.astype("<i2").tobytes()
