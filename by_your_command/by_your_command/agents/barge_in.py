"""When user speech over the robot's reply is a real barge-in (full duplex only).

At the onset the player is cut at once (no round trip); the provider is told only once the speech
proves real, so a cough or a knock resumes the reply instead of losing it:
- confirmed: the user has spoken at least `min_barge_in_ms` (audio received for the utterance);
- false: the utterance ended shorter than that, or `window_s` passed without that much speech.
An empty transcript is only known after the turn was committed (and the provider's history already
truncated), so it is counted and logged, not resumed: the history must match what was heard.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from by_your_command.agents.reply_audio import ReplyAudio


class Verdict(Enum):
    WAIT = "wait"
    CONFIRMED = "confirmed"
    FALSE = "false"


@dataclass
class PendingBargeIn:
    reply: ReplyAudio
    stream_id: str  # the stream that was cut
    started_at: float


def judge(
    speech_ms: float, utterance_ended: bool, elapsed_s: float, min_ms: float, window_s: float
) -> Verdict:
    if speech_ms >= min_ms:
        return Verdict.CONFIRMED
    if utterance_ended or elapsed_s >= window_s:
        return Verdict.FALSE
    return Verdict.WAIT
