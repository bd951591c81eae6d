"""When user speech over the robot's reply is a real barge-in (full duplex only).

At the speech onset the player pauses the reply at once (no provider round trip); the provider
is told only once the speech proves real, and then the reply is cut at what the user heard. A
cough, a knock or an "uh-huh" resumes the same reply where it paused. Proof, in that order:
- speech: at least `min_ms` of it from the VAD's onset (the VAD's pre-roll and pauses do not
  count: a 100 ms cough arrives with half a second of pre-roll);
- words (when a local transcriber runs and `min_words` > 0): at least that many words that are
  not backchannels ("uh-huh", "yeah", "okay": they mean "go on"); or, after `long_ms` of speech,
  one such word: the recogniser's small vocabulary merges words it does not know into fillers
  ("turn to the left now" over the robot came out "soon oh"), and a backchannel is short.
It is false when the utterance ended without that proof (once its whole audio is transcribed), or
when `window_s` passed without it. Pure: the runtime gathers the evidence.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from by_your_command.agents.reply_audio import ReplyAudio
from by_your_command.agents.turn import Turn

# A transcript that never catches up with a talking user (a slow machine) cannot hold the reply
# paused for ever: past this many windows the barge-in is judged on what is known.
WINDOWS_BEFORE_GIVING_UP = 2


class Verdict(Enum):
    WAIT = "wait"
    CONFIRMED = "confirmed"
    FALSE = "false"


@dataclass(frozen=True)
class Rules:
    min_ms: float
    min_words: int  # 0: speech alone decides
    window_s: float
    long_ms: float = 0.0  # speech this long needs one word that is not a backchannel (0: no such rule)


@dataclass(frozen=True)
class Evidence:
    speech_ms: float  # voiced speech heard since the onset
    ended: bool  # the utterance ended
    windows_passed: int  # whole windows since the onset (0, 1, or WINDOWS_BEFORE_GIVING_UP)
    words: int | None  # interrupting words in the latest transcript (None: none yet, or no transcriber)
    transcript_current: bool  # that transcript covers all the audio received


@dataclass
class PendingBargeIn:
    reply: ReplyAudio
    stream_id: str  # the stream that was paused
    started_at: float
    words: int | None = None  # interrupting words in the latest transcript
    transcribed_bytes: int = 0  # of the turn's audio, what that transcript covers
    transcribing: bool = False
    transcriber_failed: bool = False  # then the speech's length alone decides
    windows_judged: int = 0  # windows that had passed when it was last judged (its deadline)
    # Judged false while the user was still talking: the reply plays on, and the same utterance is
    # judged again on what follows ("yeah... no wait, go left" must not lose its second half).
    resumed: bool = False


def judge(evidence: Evidence, rules: Rules) -> Verdict:
    over = evidence.ended or evidence.windows_passed >= 1
    if evidence.speech_ms < rules.min_ms:
        return Verdict.FALSE if over else Verdict.WAIT
    if rules.min_words <= 0:
        return Verdict.CONFIRMED
    if evidence.words is not None and evidence.words >= _words_needed(evidence, rules):
        return Verdict.CONFIRMED
    if over and (evidence.transcript_current or evidence.windows_passed >= WINDOWS_BEFORE_GIVING_UP):
        return Verdict.FALSE
    return Verdict.WAIT


def _words_needed(evidence: Evidence, rules: Rules) -> int:
    long = rules.long_ms > 0 and evidence.speech_ms >= rules.long_ms
    return min(rules.min_words, 1) if long else rules.min_words


class BargeInWatch:
    """The one barge-in being judged: the paused reply, the utterance spoken over it (the first
    that starts while it is pending; held from the provider until judged), and the judge's windows.
    The runtime owns it and acts on its verdicts (times are passed in: no clock of its own)."""

    def __init__(self, rules: Rules) -> None:
        self.rules = rules
        self.pending: PendingBargeIn | None = None
        self.turn: Turn | None = None

    def start(self, reply: ReplyAudio, now: float, turn: Turn | None = None, resumed: bool = False) -> None:
        self.pending = PendingBargeIn(reply, reply.stream_id, now, resumed=resumed)
        self.turn = turn

    def join(self, turn: Turn) -> bool:
        """A new utterance: the one judged if the pending barge-in has none yet (its audio held)."""
        if self.pending is None or self.turn is not None:
            return False
        turn.held = True
        self.turn = turn
        return True

    def judges(self, turn: Turn) -> bool:
        return self.pending is not None and self.turn is turn

    def deadline(self) -> float | None:
        """The end of the next window not judged yet: a fixed time (see `windows_passed`)."""
        pending = self.pending
        if pending is None:
            return None
        return pending.started_at + (pending.windows_judged + 1) * self.rules.window_s

    def windows_passed(self, now: float) -> int:
        """0 within the window, 1 after it (a transcript still coming may be waited for), then
        WINDOWS_BEFORE_GIVING_UP: the same sums as the deadline, so a due deadline always sees it."""
        pending = self.pending
        assert pending is not None
        window = self.rules.window_s
        if now >= pending.started_at + WINDOWS_BEFORE_GIVING_UP * window:
            return WINDOWS_BEFORE_GIVING_UP
        return 1 if now >= pending.started_at + window else 0

    def evidence(self, now: float) -> Evidence:
        pending, turn = self.pending, self.turn
        assert pending is not None
        return Evidence(
            turn.voiced_ms if turn is not None else 0.0,
            turn is not None and turn.ended,
            self.windows_passed(now),
            pending.words,
            turn is not None and not pending.transcribing and pending.transcribed_bytes >= len(turn.audio),
        )

    def judge(self, now: float) -> tuple[Verdict, Evidence]:
        """The verdict on what is known now; WAIT remembers the windows seen (the next deadline)."""
        pending = self.pending
        assert pending is not None
        rules = self.rules
        if pending.transcriber_failed:
            rules = Rules(rules.min_ms, 0, rules.window_s)  # its length alone decides
        evidence = self.evidence(now)
        verdict = judge(evidence, rules)
        if verdict is Verdict.WAIT:
            pending.windows_judged = evidence.windows_passed
        return verdict, evidence

    def end(self) -> tuple[PendingBargeIn | None, Turn | None]:
        """Judged (or settled otherwise): nothing pending any more; what was."""
        ended = self.pending, self.turn
        self.pending = self.turn = None
        return ended
