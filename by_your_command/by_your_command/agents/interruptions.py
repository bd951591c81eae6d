"""Interruptions of the robot's reply (docs/agents.md, "Barge-in"): the player paused at the user's
speech over it, resumed or cut once `barge_in.py` judges that speech, and the reply cut by a safety
stop or by a full-duplex model that yielded. A cut goes to the player and, at what the listener
heard, to the model's memory; the responses cut are remembered (their late audio and words drop).

The runtime calls these from its one task (times handed in) and acts on what they return: the
reply judged (its turn may end), the transcription to run beside the scheduler (`hearing`, whose
words come back through the runtime's queue as `Heard`).
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from functools import partial

from by_your_command.agents.barge_in import BargeInWatch, PendingBargeIn, Rules, Verdict
from by_your_command.agents.config import AgentConfig
from by_your_command.agents.metrics import Counters
from by_your_command.agents.overlap_words import interrupting_words
from by_your_command.agents.port import PlayerAction, RobotPort
from by_your_command.agents.reply_audio import ReplyAudio
from by_your_command.agents.robot_runner import Publish
from by_your_command.agents.session import Interrupt, SendAudio, Session
from by_your_command.agents.turn import Turn

log = logging.getLogger(__name__)

# The transcriber hears a barge-in from this long before the VAD's onset: the onset frame comes
# tens of ms into the first word. The rest of the pre-roll (480 ms shipped) is, over a reply, the
# robot's residual echo, which the recogniser wrote as words: backchannels said over a residual
# at -60 to -38 dBFS (the user at -26; four voices, four backchannels, four levels) came out as two
# or more interrupting words in 36 of 64 trials with all of it ("uh-huh" heard "hi because"), in
# 20 heard from 160 ms before their start.
TRANSCRIBED_PRE_ROLL_MS = 160.0
RECENT_CUTS = 64  # cut responses remembered (their late audio and words are dropped); bounded

# pcm (int16 LE) and its rate -> the words heard (the app runs the recogniser on a worker thread)
Transcriber = Callable[[bytes, int], Awaitable[str]]


@dataclass(frozen=True)
class Heard:
    """What the local transcriber heard of a barge-in's audio (None: it failed)."""

    barge: PendingBargeIn
    text: str | None
    covered_bytes: int


class Interruptions:
    def __init__(
        self,
        config: AgentConfig,
        counters: Counters,
        port: RobotPort,
        transcriber: Transcriber | None,
        *,
        publish: Publish,
        wall: Callable[[], float],
        discard_stream: Callable[[str], None],
        session: Callable[[], Session | None],
    ) -> None:
        """`wall()`: the wall clock (the player's stamps); `discard_stream(id)`: drop what is
        still queued for the player of that stream; `session()`: the session open, if any."""
        self._config = config
        self._counters = counters
        self._port = port
        # Words of the speech over a reply (barge-in proof); None: its length alone decides.
        self._transcriber = transcriber if config.min_barge_in_words > 0 else None
        rules = Rules(
            config.min_barge_in_ms,
            config.min_barge_in_words if self._transcriber is not None else 0,
            config.barge_in_window_s,
            config.long_barge_in_ms,
        )
        self._watch = BargeInWatch(rules)  # the barge-in being judged, if any
        self.cut: deque[str] = deque(maxlen=RECENT_CUTS)  # responses cut, newest last
        self._publish = publish
        self._wall = wall
        self._discard_stream = discard_stream
        self._session = session

    # --- what the runtime asks ---------------------------------------------------------------

    @property
    def pending(self) -> bool:
        """A barge-in is being judged (its reply paused, or resumed and judged again)."""
        return self._watch.pending is not None

    @property
    def utterance(self) -> Turn | None:
        """The utterance over the reply, judged (held from the provider until then)."""
        return self._watch.turn

    def judging(self, reply: ReplyAudio | None) -> bool:
        """The pending barge-in is over `reply`: its turn ends when it is judged."""
        pending = self._watch.pending
        return pending is not None and pending.reply is reply

    def judges(self, turn: Turn) -> bool:
        return self._watch.judges(turn)

    def join(self, turn: Turn) -> None:
        """A new utterance: held until judged if it is the speech over a paused reply."""
        self._watch.join(turn)

    def deadline(self) -> float | None:
        return self._watch.deadline()

    def was_cut(self, response_id: str) -> bool:
        return response_id in self.cut

    # --- the flow ----------------------------------------------------------------------------

    def speech_onset(self, reply: ReplyAudio | None, now: float) -> None:
        """The user started talking (awake; not a full-duplex model): the reply still audible is
        paused, and the speech judged."""
        if (
            self._config.barge_in
            and self._watch.pending is None
            and reply is not None
            and not reply.cut
            and reply.is_playing(now)
        ):
            # Pause the player first: no provider round trip between the user's voice and silence.
            # Its audio keeps flowing to the player, which holds it: a false barge-in resumes the
            # same stream, so nothing is re-sent and played_ms stays that of the whole reply.
            self._player(reply.stream_id, "barge_in", PlayerAction.PAUSE)
            self._counters.barge_ins += 1
            self._watch.start(reply, now)
            log.info(
                "agent %s: speech over %s: paused at ~%d ms",
                self._config.agent_id,
                reply.stream_id,
                reply.heard_ms(now),
            )

    def hearing(self) -> Callable[[], Awaitable[Heard]] | None:
        """The transcription of the held speech to run (off the scheduler), when its words can
        still decide the barge-in; None: none to run now."""
        barge, turn = self._watch.pending, self._watch.turn
        if barge is None or turn is None or self._transcriber is None or barge.transcribing:
            return None
        if len(turn.audio) <= barge.transcribed_bytes or turn.voiced_ms < self._config.min_barge_in_ms:
            return None  # nothing new, or too little speech to be a barge-in whatever it says
        assert turn.resampler is not None
        barge.transcribing = True
        speech = turn.audio_from_onset(TRANSCRIBED_PRE_ROLL_MS)
        rate = turn.resampler.to_rate
        return partial(self._transcribe, self._transcriber, barge, speech, rate, len(turn.audio))

    async def _transcribe(
        self, transcriber: Transcriber, barge: PendingBargeIn, pcm: bytes, rate: int, covered_bytes: int
    ) -> Heard:
        # Beside the scheduler, in a task the runtime runs: it changes nothing here but a counter.
        text: str | None
        try:
            text = await transcriber(pcm, rate)
        except Exception as error:  # counted and logged here; the verdict then rests on length
            self._counters.internal_errors += 1
            log.error("agent %s: barge-in transcription failed: %r", self._config.agent_id, error)
            text = None
        return Heard(barge, text, covered_bytes)

    def heard(self, heard: Heard) -> bool:
        """Take what the transcriber heard; False: that barge-in was judged meanwhile."""
        barge = heard.barge
        barge.transcribing = False
        if self._watch.pending is not barge:
            return False
        barge.transcribed_bytes = heard.covered_bytes
        if heard.text is None:
            barge.words = None
            barge.transcriber_failed = True
        else:
            words = interrupting_words(heard.text, self._config.backchannels)
            barge.words = len(words)
            log.info(
                "agent %s: over the reply: %r (%d interrupting word(s))",
                self._config.agent_id,
                heard.text,
                len(words),
            )
        return True

    def judge(self, now: float, talking: Turn | None) -> ReplyAudio | None:
        """Judge the pending barge-in on what is known `now` (`talking`: the utterance still being
        received) and act on the verdict; the reply judged, None if none was (or not yet)."""
        if self._watch.pending is None:
            return None
        verdict, evidence = self._watch.judge(now)
        if verdict is Verdict.WAIT:
            return None
        barge, turn = self._watch.end()
        assert barge is not None
        reply = barge.reply
        if barge.resumed and verdict is Verdict.CONFIRMED and not reply.is_playing(now):
            verdict = Verdict.FALSE  # the reply ended meanwhile: nothing to cut, an utterance like any
            if turn is not None:
                self._release_held(turn)
        if verdict is Verdict.CONFIRMED:
            # Paused at the onset: cut where it paused; resumed since: cut where it plays now.
            heard = self._cut_reply(reply, "barge_in", now if barge.resumed else barge.started_at)
            log.info(
                "agent %s: barge-in confirmed (%.0f ms of speech, %s word(s)); %s cut at %d ms",
                self._config.agent_id,
                evidence.speech_ms,
                "?" if evidence.words is None else evidence.words,
                barge.stream_id,
                heard,
            )
            if turn is not None:
                self._release_held(turn)
        else:
            if not barge.resumed:
                self._counters.false_barge_ins += 1
                self._player(reply.stream_id, "false_barge_in", PlayerAction.RESUME)
                log.info(
                    "agent %s: false barge-in (%.0f ms of speech, %s word(s)); %s resumed",
                    self._config.agent_id,
                    evidence.speech_ms,
                    "?" if evidence.words is None else evidence.words,
                    barge.stream_id,
                )
            still_talking = turn is not None and talking is turn
            if still_talking and not reply.cut and reply.is_playing(now):
                # The reply plays on, and what follows may still prove an interruption: the same
                # utterance is judged again, a fresh window from now.
                self._watch.start(reply, now, turn, resumed=True)
            elif still_talking and turn is not None:
                self._release_held(turn)  # the reply is over: an utterance like any other
            # an utterance that ended without proof stays held: never sent, never committed
        return reply

    def model_yielded(self, reply: ReplyAudio, now: float) -> None:
        """A full-duplex model stopped talking because the user spoke: what the player still holds
        of the reply is not said."""
        heard = self._cut_reply(reply, "model_yielded", now)
        self._counters.barge_ins += 1
        log.info(
            "agent %s: the model yielded to the user; %s cut at %d ms",
            self._config.agent_id,
            reply.stream_id,
            heard,
        )

    def safety_stop(self, reply: ReplyAudio | None, now: float) -> int | None:
        """The robot heard "stop" (the player cut every reply already): a barge-in being judged is
        settled, and the reply, if any was published and not cut yet, is cut at what was heard by
        `now`; what was heard of it (ms), None if none was cut."""
        _, held = self._watch.end()
        if held is not None:
            held.held = False  # the speech is the user's
        if reply is None or reply.cut or reply.stream_started_at is None:
            return None
        return self._cut_reply(reply, "safety_stop", now)

    # --- the player and the model ------------------------------------------------------------

    def _release_held(self, turn: Turn) -> None:
        """Speech held while a barge-in was judged is the user's: the model hears it now."""
        if not turn.held:
            return
        turn.held = False
        session = self._session()
        if session is not None and turn.audio and not turn.deferred:
            session.send(SendAudio(bytes(turn.audio)))

    def _cut_reply(self, reply: ReplyAudio, reason: str, stopped_at: float) -> int:
        """Cut `reply` at the player and in the model's memory, at what was heard by `stopped_at`."""
        reply.cut = True
        self.cut.append(reply.response_id)
        heard = reply.heard_ms(stopped_at)
        self._discard_stream(reply.stream_id)
        self._player(reply.stream_id, reason, PlayerAction.CUT)
        session = self._session()
        if session is not None and session.serial == reply.session:
            session.send(Interrupt(reply.response_id, reply.item_id, heard))
        return heard

    def _player(self, stream_id: str, reason: str, action: PlayerAction) -> None:
        stamp = self._wall()
        self._publish(
            "interruption_signal",
            partial(self._port.publish_interruption, stream_id, reason, stamp, action),
        )
