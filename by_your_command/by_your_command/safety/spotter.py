"""The stop spotter: microphone blocks in, stops out. Pure and single-threaded (see worker.py).

Mic audio is cut into short utterances by level (segmenter.py) and each one is decoded as it
comes (recognizer.py: a small language model, with a keyphrase search as second opinion); at its
end the transcript is judged. Over the robot's voice its residual echo holds that end back: a
clean stop is decided earlier, at a pause well under the word's level (`Paused`). In echo_gate
mode the raw mic holds the robot's voice at full level, louder than a user a metre away: while
the robot plays (and a second after), the mic goes through the aec echo engine and its residual
suppressor (audio/echo.py, as the echo_suppressor runs them) with the played audio as reference,
and only then is it segmented (`cancel_echo`). Idle, only the level of each 20 ms frame is
computed. The reference itself is spotted too (own_voice.py): a stop heard where the robot said a
stop-like word is its own voice, and is rejected.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from by_your_command.audio.pcm import Int16Array, resample, to_mono
from by_your_command.safety.config import StopConfig
from by_your_command.safety.own_voice import OwnVoiceMarks
from by_your_command.safety.recognizer import (
    NEAR_MISSES,
    REFERENCE_PHRASE_WEIGHT,
    Heard,
    KeywordSpotter,
    StopMatcher,
    StopRecognizer,
)
from by_your_command.safety.segmenter import (
    RATE,
    Abandoned,
    Audio,
    Ended,
    LevelSegmenter,
    Paused,
    SegmentEvent,
    Started,
)
from by_your_command.vad.attention import words_of

if TYPE_CHECKING:
    from by_your_command.audio.echo import Block, EchoController

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
# 1e-30 heard 98.8 % of stops over the robot's voice (tuned voices, with "oh" alone) but stopped
# the robot on 2 of 200 of its own replies (residual echo heard "but", "oh"): not looser.
KWS_THRESHOLD = 1e-20
# While the robot speaks, a stop waits until its voice is known this far past the stop's end: a
# stop-like word it is in the middle of ("I stopped...") is recognised only at its end. The
# reference runs ahead of the mic (the room delays the mic), so the wait is short or nothing.
OWN_VOICE_LOOKAHEAD_NS = 200_000_000
OWN_VOICE_MAX_WAIT_NS = 500_000_000  # mic time: the reference stalled, decide without it
KWS_MAX_VOICED_NS = 900_000_000  # a keyphrase hit counts only in an utterance this short: one word
MIN_VOICED_NS = 150_000_000  # shorter is a click or a scrap of residual echo, not a stop phrase
# Over the robot's voice a keyphrase hit needs this much voice: after the user's chat over a reply
# the canceller, disturbed by the double talk, let 160 ms scraps of the robot's voice through,
# heard "who" with a hit (3 of 130 chat lines stopped the robot). The shortest user stop taken on
# a hit over a reply lasted 240 ms (a "freeze" heard "read"; bench_safety_stop, four voice sets).
KWS_MIN_VOICED_OVER_REPLY_NS = 200_000_000
ECHO_TAIL_NS = NS_PER_S  # keep cancelling this long after the last reference block (room tail)
# Over the robot's voice in gate mode (bench_safety_stop, tuned voices): 90.0 % of stops at 6 dB,
# 96.2 % at 3 dB, no own-voice false stops either way; a gentler band floor (-10 dB) lost stops.
ECHO_GUARD_MARGIN_DB = 3.0
REFERENCE_MAX_UTTERANCE_MS = 5000  # the robot's sentences: its stop-like words need their times
# A keyphrase hit on one word stands for a clipped stop, but not in an utterance the echo canceller
# took this much out of: that is the robot's residual echo (en-gb "I heard you" decoded "what" with
# a hit stopped the robot: 25-30 dB under the mic; users' stops over a reply came out 5-9 dB under
# it, bench_safety_stop). A whole stop phrase stands whatever the canceller took: a user 15 dB
# under a loud robot's echo at the mic must still be heard (residual echo heard "halt" early in a
# reply stopped the robot in 1 of 130 chat lines over a reply: the safe way to be wrong).
ECHO_REMOVED_DB = 15.0
# A stop transcript this long is more than a stop phrase (the longest users' stops over a reply,
# "stop stop", had 720-860 ms of voice; "stopping by the shop" 1080-1180 ms, bench_safety_stop):
# it is decoded again without the stop phrases' bias, and a near miss heard there with no stop
# word ("stopping i little") is chat. Over a reply the biased decoder heard that line "stop it
# halt" in 5 of 23 voices; unbiased, 4 of them came out "stopping ...", no real stop did.
NEAR_MISS_CHECK_NS = 900_000_000
LEVELS_KEPT_NS = 4 * NS_PER_S  # mic and output levels remembered: longer than any stop utterance


class _Levels:
    """Mean squares of recent blocks by time: how loud a stretch of the mic (or output) was."""

    def __init__(self) -> None:
        self._blocks: deque[tuple[int, int, float]] = deque()  # (start ns, end ns, mean square)

    def add(self, pcm: Int16Array, rate: int, start_ns: int) -> None:
        if len(pcm) == 0:
            return
        end_ns = start_ns + len(pcm) * NS_PER_S // rate
        self._blocks.append((start_ns, end_ns, float(np.mean(np.square(pcm.astype(np.float64))))))
        while self._blocks and self._blocks[0][1] < end_ns - LEVELS_KEPT_NS:
            self._blocks.popleft()

    def energy(self, start_ns: int, end_ns: int) -> float:
        """Mean square x overlapping ns over [start, end): 0.0 when nothing was recorded there."""
        return sum(
            square * (min(end, end_ns) - max(start, start_ns))
            for start, end, square in self._blocks
            if start < end_ns and end > start_ns
        )


@dataclass(frozen=True)
class Detection:
    text: str  # what was heard
    voice_start_ns: int
    voice_end_ns: int  # end of the last word (mic clock)


class StopSpotter:
    def __init__(self, config: StopConfig, cancel_echo: bool, voice_sample: Int16Array | None = None) -> None:
        """`voice_sample`: the robot's voice (16 kHz) to prime the decoder of its played voice
        with: new, that decoder heard the robot's first words after a start stop-like, and a
        user's stop right after them was rejected as the robot's own."""
        self.config = config
        phrases = config.stop_phrases
        self.matcher = StopMatcher(phrases, config.max_other_words)
        self._mic_recognizer = StopRecognizer(phrases, streaming=True)
        # At a pause the streaming decoder's best guess so far is rougher than a decode of the
        # whole audio ("halt" heard "call", "freeze" "three"): the pause decodes it again.
        self._pause_recognizer = StopRecognizer(phrases, streaming=False)
        self._utterance: list[Int16Array] = []  # the open utterance's audio, for that decode
        # A long stop's second opinion, without the stop phrases' bias (NEAR_MISS_CHECK_NS).
        self._plain_recognizer = StopRecognizer(phrases, streaming=False, phrase_weight=1)
        self._reference_recognizer = StopRecognizer(
            phrases, streaming=True, phrase_weight=REFERENCE_PHRASE_WEIGHT, accents=False
        )
        if voice_sample is not None:
            self._reference_recognizer.prime(voice_sample)
        self._keywords = KeywordSpotter(phrases, KWS_THRESHOLD)

        self._mic = LevelSegmenter(
            config.min_level_dbfs, config.onset_db, config.end_silence_ms, config.max_utterance_ms
        )
        self._reference = LevelSegmenter(
            config.min_level_dbfs, config.onset_db, config.end_silence_ms, REFERENCE_MAX_UTTERANCE_MS
        )
        self._reference_start = 0
        self._end_silence_ns = config.end_silence_ms * 1_000_000
        self.marks = OwnVoiceMarks(config.own_voice_window_ms)
        self._echo: EchoController | None = _echo_controller() if cancel_echo else None
        self._reference_until = 0  # end of the latest reference block (its clock = the mic's)
        self._cancelling = False
        self._cancelled_ns = 0  # mic time of the next sample out of the echo controller
        self._last_stop_ns: int | None = None
        self._decided = False  # the open utterance's stop was decided at a pause
        self._mic_start_ns = 0  # the open utterance's first sample (pre-roll included)
        self._pending: list[Detection] = []  # heard while the robot spoke: its voice not known yet
        self._mic_levels = _Levels()  # the raw mic while cancelling
        self._output_levels = _Levels()  # the canceller's output
        self.heard = 0  # utterances decoded
        self.stops = 0
        self.own_voice = 0  # stops rejected as the robot's own voice
        self.residual_echo = 0  # keyphrase hits rejected as what the canceller left of the robot
        self.near_misses = 0  # long stop transcripts heard, unbiased, as a word like a stop
        self.repeated = 0  # stops within the refractory window of the last one
        self.last_text = ""

    @property
    def cancelling(self) -> bool:
        return self._cancelling

    @property
    def echo_controller(self) -> EchoController | None:
        """The canceller of the robot's voice (None when not cancelling it): what it learned
        is kept across restarts by the node (audio/echo_memory.py)."""
        return self._echo

    def reference(self, pcm: Int16Array, sample_rate: int, channels: int, start_ns: int) -> None:
        """A block the player played, stamped with its play time."""
        mono = to_mono(pcm, channels)
        if self._echo is not None:
            self._echo.add_reference(mono, sample_rate, 1, start_ns)
        pcm16 = resample(mono, sample_rate, RATE)
        self._reference_until = max(self._reference_until, start_ns + len(mono) * NS_PER_S // sample_rate)
        for event in self._reference.push(pcm16, start_ns):
            self._reference_event(event)

    def _reference_event(self, event: SegmentEvent) -> None:
        recognizer = self._reference_recognizer
        if isinstance(event, Started):
            self._reference_start = event.start_ns
            recognizer.start()
        elif isinstance(event, Audio):
            recognizer.feed(event.pcm)
        elif isinstance(event, Abandoned):
            recognizer.abandon()
        elif isinstance(event, Ended):
            self._mark_own_words(recognizer.finish())

    def _mark_own_words(self, heard: Heard) -> None:
        for word, start_s, end_s in heard.words:
            if self.matcher.stop_like(word):
                start = self._reference_start + int(start_s * NS_PER_S)
                self.marks.mark(start, self._reference_start + int(end_s * NS_PER_S))

    def mic(self, pcm: Int16Array, sample_rate: int, channels: int, start_ns: int) -> list[Detection]:
        """A microphone block captured from `start_ns`; the stops it completes (at most one)."""
        mono = to_mono(pcm, channels)
        if self._reference.active and start_ns > self._reference_until + self._end_silence_ns:
            # The player stopped publishing: its last word ends without the quiet after it.
            for event in self._reference.close():
                self._reference_event(event)
        blocks = self._echo_cancelled(mono, sample_rate, start_ns)
        # Over the robot's voice its residual echo sits above the floor after a stop and held the
        # stop's end back (p95 +330 ms): a pause under the stop's level decides a clean stop.
        self._mic.end_drop_db = self.config.end_drop_db if self._cancelling else None
        if self._cancelling:
            self._mic_levels.add(mono, sample_rate, start_ns)
            for block, stamp in blocks:
                self._output_levels.add(block, RATE, stamp)
        found: list[Detection] = []
        for block, stamp in blocks:
            for event in self._mic.push(block, stamp):
                detection = self._mic_event(event)
                if detection is not None:
                    self._pending.append(detection)
            found += self._settle(stamp)
        return found

    def _settle(self, mic_ns: int) -> list[Detection]:
        decided, waiting = [], []
        for detection in self._pending:
            due = detection.voice_end_ns + OWN_VOICE_LOOKAHEAD_NS
            known = not self._reference.active or self._reference_until >= due
            if known or mic_ns >= detection.voice_end_ns + OWN_VOICE_MAX_WAIT_NS:
                if self._accepted(detection):
                    decided.append(detection)
            else:
                waiting.append(detection)
        self._pending = waiting
        return decided

    def _echo_cancelled(self, mono: Int16Array, rate: int, start_ns: int) -> list[tuple[Int16Array, int]]:
        echo = self._echo
        playing = echo is not None and start_ns < self._reference_until + ECHO_TAIL_NS
        if echo is None or not (playing or self._cancelling):
            return [(resample(mono, rate, RATE), start_ns)]
        if not playing:  # the robot's voice has died away: back to the raw mic (cancelling costs CPU)
            self._cancelling = False
            out = self._restamped(echo.drain())
            echo.set_assistant_speaking(False, start_ns)
            return [*out, (resample(mono, rate, RATE), start_ns)]
        if not self._cancelling:
            self._cancelling = True
            self._cancelled_ns = start_ns
            echo.set_assistant_speaking(True, start_ns)
        return self._restamped(echo.process(mono, start_ns, start_ns, rate))

    def _restamped(self, blocks: list[Block]) -> list[tuple[Int16Array, int]]:
        """The controller's output runs on without the gaps between the robot's replies (it only
        hears the mic while the robot plays): its blocks are laid from where cancelling began."""
        out = []
        for block in blocks:
            out.append((block.pcm, self._cancelled_ns))
            self._cancelled_ns += len(block.pcm) * NS_PER_S // RATE
        return out

    def _mic_event(self, event: SegmentEvent) -> Detection | None:
        recognizer = self._mic_recognizer
        if isinstance(event, Started):
            recognizer.start()
            self._keywords.start()
            self._decided = False
            self._mic_start_ns = event.start_ns
            self._utterance = []
        elif isinstance(event, Paused):
            # Once decided, the utterance's later pauses ("stop | stop") are the same stop.
            return None if self._decided else self._clean_stop_so_far(event)
        elif isinstance(event, Audio):
            recognizer.feed(event.pcm)
            self._keywords.feed(event.pcm)
            self._utterance.append(event.pcm)
        elif isinstance(event, Abandoned):
            recognizer.abandon()
            self._keywords.finish()
        else:
            heard = recognizer.finish()
            keyword = self._keywords.finish()
            self.heard += 1
            self.last_text = heard.text
            voiced = event.voice_end_ns - event.voice_start_ns
            if voiced < MIN_VOICED_NS or self._decided:
                return None
            detection = Detection(heard.text, event.voice_start_ns, event.voice_end_ns)
            if self.matcher.is_stop(heard.text):
                return None if voiced >= NEAR_MISS_CHECK_NS and self._near_miss(heard.text) else detection
            if (
                keyword
                and voiced <= KWS_MAX_VOICED_NS
                and (voiced >= KWS_MIN_VOICED_OVER_REPLY_NS or not self._cancelling)
                and self.matcher.may_be_stop(heard.text)
            ):
                if not self._mostly_echo(event.voice_start_ns, event.voice_end_ns):
                    return detection
                self.residual_echo += 1
                log.info("stop heard (%r) rejected: the robot's residual echo", heard.text)
        return None

    def _clean_stop_so_far(self, pause: Paused) -> Detection | None:
        """A stop phrase and nothing else (fillers aside) before a pause under its level: decided
        now. Anything more waits for the utterance's end: chat paused at a weak consonant ("our
        stop | flight to Boston", "don't | stop believing") is judged whole (cut there, 21 % of
        chat lines over a reply stopped the robot)."""
        voiced = pause.voice_end_ns - pause.voice_start_ns
        if voiced < MIN_VOICED_NS:
            return None
        # The words begun before the pause: after it the decoder hears the residual echo.
        said = " ".join(
            word
            for word, start_s, _ in self._decoded_whole(self._pause_recognizer).words
            if self._mic_start_ns + int(start_s * NS_PER_S) < pause.voice_end_ns
        )
        if not self.matcher.is_clean_stop(said):
            return None
        self._decided = True
        self.last_text = said
        return Detection(said, pause.voice_start_ns, pause.voice_end_ns)

    def _near_miss(self, heard: str) -> bool:
        """The utterance decoded again without the stop phrases' bias holds a word like a stop
        ("stopping", "stopwatch") and no stop word: it was chat."""
        plain = words_of(self._decoded_whole(self._plain_recognizer).text)
        if not any(w in NEAR_MISSES for w in plain) or any(w in self.matcher.words for w in plain):
            return False
        self.near_misses += 1
        log.info("stop heard (%r) rejected: unbiased, it was %r", heard, " ".join(plain))
        return True

    def _decoded_whole(self, recognizer: StopRecognizer) -> Heard:
        """The open utterance so far, decoded again by `recognizer` (not streaming)."""
        recognizer.start()
        for pcm in self._utterance:
            recognizer.feed(pcm)
        return recognizer.finish()

    def _mostly_echo(self, start_ns: int, end_ns: int) -> bool:
        """The echo canceller took ECHO_REMOVED_DB or more out of the mic over [start, end)."""
        mic = self._mic_levels.energy(start_ns, end_ns)
        return mic > 0.0 and self._output_levels.energy(start_ns, end_ns) < mic * 10 ** (
            -ECHO_REMOVED_DB / 10
        )

    def _accepted(self, detection: Detection) -> bool:
        if self._reference.active:
            # The robot is still saying its sentence: its words so far (the room delays the mic,
            # so the reference is ahead of what was just heard).
            self._mark_own_words(self._reference_recognizer.partial())
        if self.marks.covers(detection.voice_start_ns, detection.voice_end_ns):
            self.own_voice += 1
            log.info("stop heard (%r) rejected: the robot's own voice", detection.text)
            return False
        last = self._last_stop_ns
        if last is not None and detection.voice_end_ns - last < self.config.refractory_ms * 1_000_000:
            self.repeated += 1
            return False
        self._last_stop_ns = detection.voice_end_ns
        self.stops += 1
        return True


def _echo_controller() -> EchoController | None:
    try:
        from by_your_command.audio.echo import EchoConfig, EchoController

        # With its residual suppressor, as the echo_suppressor runs it: the linear filter alone
        # leaves a residual the level segmenter would take for one long utterance; the suppressor
        # mutes what is not clearly louder than it, so the user's stop stands out on its own.
        # Its margin is gentler than the echo_suppressor's 6 dB: that took the start of a stop.
        return EchoController(EchoConfig(mode="aec", echo_guard_margin_db=ECHO_GUARD_MARGIN_DB))
    except ImportError as error:
        log.warning("stop spotter without echo cancellation (%s): the robot's voice may hide a stop", error)
        return None
