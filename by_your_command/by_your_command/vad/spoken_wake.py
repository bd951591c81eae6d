"""Spoken wake-up while asleep, decided on the robot: asleep audio never leaves it.

`WakeRecognizer` decodes one utterance with pocketsphinx (its en-us model ships in the wheel; no
download) against a small n-gram language model built at startup from the wake phrases plus a
garbage vocabulary of a few hundred everyday words, negations among them. Out-of-grammar speech is
transcribed into garbage words ("don't awaken baby", "can't wakeup early") instead of being forced
into a wake phrase, and the transcript must then pass the same `PhraseMatcher` as `prompt_text`:
the whole utterance one wake phrase, filler words and the robot's name only at its edges, no
negation. A JSGF grammar with a garbage loop was tried first: pocketsphinx's FSG search took 7-10 s
per utterance with it, and a bare grammar scored against a phone loop did not separate "wake me at
seven" from "wake up".

`UtteranceCollector` turns the segmenter's chunks into whole utterances (bounded), and `WakeWorker`
decodes them off the caller's thread with at most one utterance waiting. No rclpy here.
"""

from __future__ import annotations

import io
import logging
import tempfile
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from by_your_command.audio.pcm import Int16Array, resample
from by_your_command.vad.attention import PhraseCommand, PhraseMatcher, words_of
from by_your_command.vad.segmenter import Event, UtteranceChunk

log = logging.getLogger(__name__)

SAMPLE_RATE = 16000  # the en-us acoustic model's rate
MAX_UTTERANCE_S = 4.0  # a wake phrase with pre-roll and hangover is ~2 s; longer is chat
# pocketsphinx mis-decodes audio padded with digital silence (file playback, gated input);
# a fixed, seeded noise floor at about -61 dBFS makes decoding stable and repeatable.
NOISE_FLOOR_STD = 30.0
WAKE_WEIGHT = 5  # how many times each wake phrase appears in the LM text (its prior)
# Everyday words the rest of speech is transcribed into. Negations and question words matter
# most: they must show up in the transcript so that the phrase matcher can refuse it.
GARBAGE_WORDS = """
a about after again all also am an and any are as ask at away back bad be because bed been before
being behind best better big bit book both bring but buy by call came can can't car come could cup
day did didn't do does doesn't dog don't done door down each early eat end even ever every eye far
feel find fine first five for forward four friend from get give go going good got great had has
have he head hear hello help her here him his home hot house how i i'm if in into is isn't it it's
just keep kind kitchen know last late later leave left let like little live long look lot love made
make man many may maybe me mean might mind more morning most move much music must my name need
never new next nice night no not now of off oh ok okay old on once one only open or other our out
over people pick place play please put rain read really right room said same saw say school see
seven she should show side sit sleep so some something soon sorry start still stop sure table take
talk tell than thank thanks that the their them then there these they thing think this those three
time to today told too took turn two under up us use very wait walk want was water way we weather
week well went were what when where which while who why will window with won't woman work would
yeah year yes yet you your baby hey hi alright um uh
""".split()


class RecognizerUnavailableError(RuntimeError):
    """pocketsphinx is not installed: spoken wake cannot run."""


@dataclass(frozen=True)
class WakeResult:
    text: str  # what the recognizer heard (garbage words included)
    wake: bool  # the whole utterance is a wake phrase


class WakeRecognizer:
    """Says whether one utterance (16-bit PCM) is a spoken wake phrase. Not thread-safe."""

    def __init__(
        self, wake_phrases: Iterable[str], sleep_phrases: Iterable[str] = (), robot_name: str = ""
    ) -> None:
        dictionary = pronunciations()
        wake_phrases, sleep_phrases = list(wake_phrases), list(sleep_phrases)
        self._matcher = PhraseMatcher(wake_phrases, sleep_phrases, robot_name)

        def known(words: list[str]) -> bool:
            return all(word in dictionary for word in words)

        wakes = [" ".join(words_of(p)) for p in wake_phrases if known(words_of(p))]
        skipped = [p for p in wake_phrases if not known(words_of(p))]
        if skipped:
            log.warning("wake phrases not in the pronouncing dictionary, cannot be spoken: %s", skipped)
        if not wakes:
            raise ValueError(f"no wake phrase can be spoken (every one has an unknown word): {wake_phrases}")
        extra = [w for p in [*sleep_phrases, robot_name] for w in words_of(p)]
        vocabulary = sorted({w for w in [*GARBAGE_WORDS, *extra] if known([w])})
        # One "sentence" per garbage word and WAKE_WEIGHT per wake phrase: a unigram-ish model in
        # which a wake phrase is likely but any other speech has words of its own to go to.
        text = "\n".join(vocabulary + [p for p in wakes for _ in range(WAKE_WEIGHT)]) + "\n"
        self._recognizer = SmallVocabulary(text, dictionary, MAX_UTTERANCE_S)
        self.phrases = tuple(wakes)

    def transcribe(self, pcm: Int16Array, sample_rate: int) -> str:
        return self._recognizer.transcribe(pcm, sample_rate)

    def recognize(self, pcm: Int16Array, sample_rate: int) -> WakeResult:
        text = self.transcribe(pcm, sample_rate)
        return WakeResult(text, self._matcher.match(text) is PhraseCommand.WAKE)


def small_lm_decoder(text: str, dictionary: dict[str, list[str]]) -> Any:
    """A pocketsphinx decoder whose language model is `text` (one sentence per line; a word's share
    of the lines is its prior), with only those words' pronunciations (loading all 135k entries of
    the dictionary takes seconds)."""
    from pocketsphinx import Decoder  # type: ignore[import-untyped]
    from pocketsphinx.lm import ArpaBoLM  # type: ignore[import-untyped]

    model = ArpaBoLM(text=text, add_start=True, case="lower")
    model.compute()
    arpa = io.StringIO()
    model.write(arpa)
    with tempfile.TemporaryDirectory(prefix="byc_lm_") as tmp:
        lm, words = Path(tmp) / "small.arpa", Path(tmp) / "small.dict"
        lm.write_text(arpa.getvalue(), encoding="utf-8")
        spoken = sorted(set(text.split()))
        words.write_text("".join(f"{e}\n" for w in spoken for e in dictionary[w]), encoding="utf-8")
        return Decoder(samprate=SAMPLE_RATE, loglevel="FATAL", lm=str(lm), dict=str(words))


class SmallVocabulary:
    """pocketsphinx decoding one utterance at a time against `small_lm_decoder(text)`. Not thread-safe."""

    def __init__(self, text: str, dictionary: dict[str, list[str]], max_s: float) -> None:
        self._decoder = small_lm_decoder(text, dictionary)
        self._noise = np.random.default_rng(0).normal(0.0, NOISE_FLOOR_STD, int(max_s * SAMPLE_RATE))

    def transcribe(self, pcm: Int16Array, sample_rate: int) -> str:
        """What was said in `pcm` (at most max_s of it is decoded)."""
        if sample_rate != SAMPLE_RATE:
            pcm = resample(pcm, sample_rate, SAMPLE_RATE)
        pcm = pcm[: len(self._noise)]
        noisy = np.clip(pcm.astype(np.float64) + self._noise[: len(pcm)], -32768, 32767).astype(np.int16)
        self._decoder.start_utt()
        try:
            self._decoder.process_raw(noisy.tobytes(), full_utt=True)
        finally:
            self._decoder.end_utt()
        hyp = self._decoder.hyp()
        return str(hyp.hypstr) if hyp is not None else ""


def pronunciations() -> dict[str, list[str]]:
    """The pocketsphinx wheel's en-us dictionary; RecognizerUnavailableError without pocketsphinx."""
    try:
        from pocketsphinx import Config
    except ImportError as error:
        raise RecognizerUnavailableError(
            f"pocketsphinx is not installed ({error}); `pip install pocketsphinx==5.1.1`"
        ) from error
    return _pronunciations(Path(Config()["dict"]))


def _pronunciations(path: Path) -> dict[str, list[str]]:
    """A CMU pronouncing dictionary's lines by word ("word(2)" is a second pronunciation)."""
    entries: dict[str, list[str]] = {}
    with path.open(encoding="utf-8") as lines:
        for line in lines:
            if line.strip():
                entries.setdefault(line.split(" ", 1)[0].split("(", 1)[0], []).append(line.rstrip("\n"))
    return entries


class UtteranceCollector:
    """Joins one utterance's chunks; an utterance longer than `max_samples` is dropped whole."""

    def __init__(self, max_samples: int = int(MAX_UTTERANCE_S * SAMPLE_RATE)) -> None:
        self._max = max_samples
        self._parts: list[Int16Array] = []
        self._length = 0
        self._too_long = False
        self.too_long = 0  # utterances dropped for their length

    def feed(self, events: Iterable[Event]) -> list[tuple[Int16Array, int]]:
        """Whole utterances (pcm, sample_rate) that ended in `events`."""
        done = []
        for event in events:
            if not isinstance(event, UtteranceChunk):
                continue
            if not self._too_long:
                self._length += len(event.samples)
                self._too_long = self._length > self._max
                self._parts.append(event.samples)
                if self._too_long:
                    self._parts = []
            if event.is_utterance_end:
                if self._too_long:
                    self.too_long += 1
                elif self._parts:
                    done.append((np.concatenate(self._parts), event.sample_rate))
                self.reset()
        return done

    def reset(self) -> None:
        self._parts, self._length, self._too_long = [], 0, False


class WakeWorker:
    """Decodes utterances on its own thread; at most one waits, a newer one replaces it.

    `on_done(tag, result)` and `on_error(tag, error)` run on the worker thread; a recognizer
    exception is counted and reported, and the worker goes on.
    """

    def __init__(
        self,
        recognize: Callable[[Int16Array, int], WakeResult],
        on_done: Callable[[int, WakeResult], None],
        on_error: Callable[[int, Exception], None],
    ) -> None:
        self._recognize = recognize
        self._on_done = on_done
        self._on_error = on_error
        self._cv = threading.Condition()
        self._pending: tuple[int, Int16Array, int] | None = None
        self._closed = False
        self.decoded = 0
        self.dropped = 0  # replaced while waiting
        self.errors = 0
        self._thread = threading.Thread(target=self._run, name="spoken_wake", daemon=True)
        self._thread.start()

    def submit(self, tag: int, pcm: Int16Array, sample_rate: int) -> None:
        with self._cv:
            if self._pending is not None:
                self.dropped += 1
            self._pending = (tag, pcm, sample_rate)
            self._cv.notify()

    def close(self, timeout: float = 2.0) -> None:
        with self._cv:
            self._closed = True
            self._pending = None
            self._cv.notify()
        self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._cv:
                while self._pending is None and not self._closed:
                    self._cv.wait()
                if self._closed:
                    return
                assert self._pending is not None
                tag, pcm, rate = self._pending
                self._pending = None
            try:
                result = self._recognize(pcm, rate)
            except Exception as error:  # a decoder failure must not end spoken wake
                self.errors += 1
                try:
                    self._on_error(tag, error)
                except Exception:  # the consumer is gone (shutdown): nothing left to tell
                    log.exception("spoken wake error callback failed")
                continue
            self.decoded += 1
            try:
                self._on_done(tag, result)
            except Exception:
                log.exception("spoken wake callback failed")
