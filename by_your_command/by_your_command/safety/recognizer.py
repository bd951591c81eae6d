"""Stop phrases decoded on the robot with pocketsphinx, streaming, and judged as a whole utterance.

A small n-gram model (built at startup, ~100 ms, as in vad/spoken_wake.py) holds the stop
phrases, weighted, plus a few hundred everyday garbage words and the stop-like words that must
not stop ("stopping", "stopwatch", "bus"): speech that is not a stop is transcribed into them
instead of being forced into a stop. pocketsphinx's keyphrase search alone was tried: cheaper
(~3 % of a core while speech plays), but it fires on "stopping", "stopwatch" and "don't stop
believing" alike, as it sees no word around the keyword. It runs beside the model as a second
opinion (`KeywordSpotter`): a short "stop" the model heard as "saw" or "show" (espeak voices)
still stops when the keyphrase search heard it and the transcript holds no negation or near miss.

`StopMatcher` judges a transcript: a whole stop phrase ("it" alone is not "stop it"), no
negation before it ("don't stop"; one after it takes nothing back), and at most
`max_other_words` other words (filler words not counted): lenient on purpose, a missed stop is
worse than a spurious one. That is also why the keyphrase override stays although it takes some
one-syllable coughs ("ha" heard "car") for a stop: without it the bench's espeak stops lost ~3 %
(4 of 130), and coughs still stopped the robot through the model writing "halt" for them (19 of
78 without it, 24 with it).

The stop words also get British pronunciations (`ACCENT_VARIANTS`) on the microphone's decoder,
not on the robot's reference (there they found "stop" in "red cup").
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from by_your_command.audio.pcm import Int16Array
from by_your_command.vad.attention import FILLER_WORDS, NEGATIONS, words_of
from by_your_command.vad.spoken_wake import (
    GARBAGE_WORDS,
    _pronunciations,
    pronunciations,
    small_lm_decoder,
)

SAMPLE_RATE = 16000
PHRASE_WEIGHT = 20  # how many times each stop phrase appears in the LM text (its prior)
# The robot's own clean voice is transcribed without that bias: with it, "red cup" and "plant"
# came out as "stop" and "halt", and the user's stops over them were taken for the robot's echo.
REFERENCE_PHRASE_WEIGHT = 1
NOISE_FLOOR_STD = 30.0  # see spoken_wake: pocketsphinx mis-decodes digital silence
FRAME_S = 0.01  # pocketsphinx's frame
# Words with a stop in them that are not one: in the model, so that speech can go to them. Not
# "stopped", "halted": spoken alone they are heard as a stop (leaning to stopping). The robot's
# own "Stopping." is also rejected by its reference (own_voice.py).
NEAR_MISSES = "stopping stopwatch bus believing freezer nonstop".split()
# Words people say to a robot, alone too, that the everyday vocabulary lacks: "Robot?" came out
# "room halt" (bench_safety_stop lone_words) and stopped it. Heard as itself, it is no clipped
# stop either: the keyphrase search fires on its "-bot", so it takes a keyphrase hit's standing
# away as a near miss does.
ADDRESS_WORDS = ("robot",)
# Garbage words a short stop is mistaken for (espeak voices, bench/bench_safety_stop.py): left out
# of the model, so that a clipped "stop" still goes to "stop". The cost: "I saw" alone may stop.
# (Also leaving out "only", "call", "lot", "also", "oh", heard for a "halt" or British "stop" over
# the robot's voice, heard no more stops on the tuned voices, and one more of the robot's own replies
# stopped it: residual echo heard "on" with a keyphrase hit.)
CONFUSABLE = frozenset("saw tell still told old all both so open talk over going".split())
# One-word transcripts that stand for a stop by themselves, keyphrase hit or not (bench/
# bench_safety_stop.py, over the robot's voice): "don't", a "stop" whose /s/ was clipped (alone it
# negates nothing, and "Don't!" means stop), and "won't", a "halt". Held-out voices over a reply:
# 44 -> 47 of 50 stops, own replies and chat unchanged. Not marked as the robot's own stop words
# (`stop_like`): its reference was heard "don't" in words that were not, and 2 of 80 user stops
# were then rejected as its echo. Not "stopping" (a clipped "stop it"): the robot's own
# "Stopping." played into the mic then stopped it; not "oh": with a looser keyphrase threshold it
# let the robot's own replies stop it.
HEARD_FOR_A_STOP = frozenset({"don't", "won't"})
# Accents the en-us dictionary lacks: the British short o of "stop" and "halt" (/ɒ/: "stop" in
# en-gb voices was heard as "call" or "don't"), as extra pronunciations of the stop words.
ACCENT_VARIANTS: dict[str, tuple[str, ...]] = {"stop": ("S T AO P",), "halt": ("HH AA L T",)}


def with_accents(dictionary: dict[str, list[str]], words: Iterable[str]) -> dict[str, list[str]]:
    """`dictionary` (word -> its lines) with `ACCENT_VARIANTS` of `words` added as "word(n)" lines."""
    out = dict(dictionary)
    for word in words:
        if word not in out:
            continue
        lines = list(out[word])
        known = {line.split(" ", 1)[1].strip() for line in lines}
        lines += [
            f"{word}({len(lines) + 1 + n}) {phones}"
            for n, phones in enumerate(p for p in ACCENT_VARIANTS.get(word, ()) if p not in known)
        ]
        out[word] = lines
    return out


@dataclass(frozen=True)
class Heard:
    text: str
    words: tuple[tuple[str, float, float], ...]  # (word, start s, end s) from the utterance start


class StopMatcher:
    def __init__(self, phrases: Iterable[str], max_other_words: int) -> None:
        self.phrases = tuple(" ".join(words_of(p)) for p in phrases)
        self.words = frozenset(w for p in self.phrases for w in words_of(p))
        # Words like a stop ("stopping", "halted"): the robot saying them is its own voice.
        self._stems = tuple(sorted(w for w in self.words if len(w) >= 4))
        self._max_other = max_other_words

    def is_stop(self, text: str) -> bool:
        words = [w for w in words_of(text) if w not in FILLER_WORDS]
        return bool(self.phrases_in(text)) or (len(words) == 1 and words[0] in HEARD_FOR_A_STOP)

    def is_clean_stop(self, text: str) -> bool:
        """Stop phrases and filler words only."""
        return bool(self.phrases_in(text, max_other=0))

    def phrases_in(self, text: str, max_other: int | None = None) -> tuple[str, ...]:
        """The stop phrases the transcript holds, if it is a stop (else ()): whole phrases only ("it"
        alone is not "stop it"), no negation, at most `max_other_words` words outside them."""
        words = [w for w in words_of(text) if w not in FILLER_WORDS]
        found, covered = [], [False] * len(words)
        for phrase in sorted(self.phrases, key=lambda p: -len(p.split())):  # "stop it" before "stop"
            size = len(phrase.split())
            for start in range(len(words) - size + 1):
                if " ".join(words[start : start + size]) == phrase and not any(covered[start : start + size]):
                    found.append(phrase)
                    covered[start : start + size] = [True] * size
        others = covered.count(False)
        if not found or others > (self._max_other if max_other is None else max_other):
            return ()
        # A negation before the stop negates it ("don't stop"); after it, it is no taking back
        # ("stop, don't!"), and a second "stop" whose /s/ the echo guard took is heard "don't".
        first = covered.index(True)
        return () if any(_negation(w) for w in words[:first]) else tuple(found)

    def may_be_stop(self, text: str) -> bool:
        """One word, no negation, no near miss: a keyphrase hit may stand. (Nothing heard at all
        is residual echo or noise, where the keyphrase search fires on its own; two words are a
        short command: "wake up", heard "we cup", fired the keyphrase search in the demo.)"""
        words = [w for w in words_of(text) if w not in FILLER_WORDS]
        if any(_negation(w) or w in NEAR_MISSES or w in ADDRESS_WORDS for w in words):
            return False
        return len(words) == 1

    def stop_like(self, word: str) -> bool:
        return word in self.words and len(word) >= 4 or word.startswith(self._stems)


def _negation(word: str) -> bool:
    return word.replace("'", "") in NEGATIONS or word.endswith("n't")


class KeywordSpotter:
    """pocketsphinx's keyphrase search for the stop phrases' words, streaming: a second opinion
    for short utterances the language model heard as something else ("saw", "show")."""

    def __init__(self, phrases: Iterable[str], threshold: float) -> None:
        from pocketsphinx import Config, Decoder  # type: ignore[import-untyped]

        dictionary = _pronunciations(Path(Config()["dict"]))
        words = sorted({w for p in phrases for w in words_of(p) if len(w) >= 4 and w in dictionary})
        # The keyphrase search takes a word's first pronunciation only: each one is its own key.
        keyed = with_accents(dictionary, words)
        lines = [f"{w}_{n} {line.split(' ', 1)[1]}" for w in words for n, line in enumerate(keyed[w])]
        with tempfile.TemporaryDirectory(prefix="byc_kws_") as tmp:
            keys, lexicon = Path(tmp) / "stop.kws", Path(tmp) / "stop.dict"
            keys.write_text("".join(f"{k.split()[0]} /{threshold:g}/\n" for k in lines), encoding="utf-8")
            lexicon.write_text("".join(f"{line}\n" for line in lines), encoding="utf-8")
            self._decoder = Decoder(samprate=SAMPLE_RATE, loglevel="FATAL", kws=str(keys), dict=str(lexicon))
        self._open = False
        self.hit = False

    def start(self) -> None:
        if self._open:
            self._decoder.end_utt()
        self._decoder.start_utt()
        self._open, self.hit = True, False

    def feed(self, pcm: Int16Array) -> None:
        if not self._open or self.hit:
            return
        self._decoder.process_raw(np.ascontiguousarray(pcm, dtype=np.int16).tobytes(), full_utt=False)
        self.hit = self._decoder.hyp() is not None

    def finish(self) -> bool:
        if self._open:
            self._decoder.end_utt()
            self._open = False
        return self.hit


class StopRecognizer:
    """Streaming decoder of one utterance at a time (16 kHz int16). Not thread-safe."""

    def __init__(
        self,
        phrases: Iterable[str],
        streaming: bool = False,
        phrase_weight: int = PHRASE_WEIGHT,
        accents: bool = True,
    ) -> None:
        phrases = [" ".join(words_of(p)) for p in phrases]
        dictionary = pronunciations()  # RecognizerUnavailableError without pocketsphinx
        if accents:
            dictionary = with_accents(dictionary, {w for p in phrases for w in p.split()})
        unknown = sorted({w for p in phrases for w in p.split() if w not in dictionary})
        if unknown:
            raise ValueError(
                f"stop_phrases: {unknown} not in the pronouncing dictionary, cannot be spotted; "
                "use other words"
            )
        vocabulary = sorted(
            {w for w in [*GARBAGE_WORDS, *NEAR_MISSES, *ADDRESS_WORDS] if w in dictionary}
            - set(phrases)
            - CONFUSABLE
        )
        text = "\n".join(vocabulary + [p for p in phrases for _ in range(phrase_weight)]) + "\n"
        self._decoder = small_lm_decoder(text, dictionary)
        self._noise = np.random.default_rng(0).normal(0.0, NOISE_FLOOR_STD, SAMPLE_RATE).astype(np.float32)
        self._offset = 0
        self._open = False
        # Streaming decodes as the audio comes (partial results, used on the robot's reference);
        # otherwise the utterance is decoded whole at its end, with its own cepstral mean: more
        # accurate on a short word (a streaming start has only a prior mean), ~40-70 ms later.
        self._streaming = streaming
        self._held: list[Int16Array] = []
        self.samples_decoded = 0

    def start(self) -> None:
        if self._open and self._streaming:
            self._decoder.end_utt()
        if self._streaming:
            self._decoder.start_utt()
        self._held = []
        self._open = True

    def prime(self, pcm: Int16Array) -> None:
        """Decode `pcm` and forget its words. A streaming decoder's cepstral mean starts as a
        prior and follows what it hears: after a sample of a voice it starts from that voice's
        mean (the robot's first words, decoded with the prior, were heard stop-like)."""
        self.start()
        self.feed(pcm)
        self.finish()

    def feed(self, pcm: Int16Array) -> None:
        if not self._open or not len(pcm):
            return
        noise = np.resize(np.roll(self._noise, -self._offset), len(pcm))
        self._offset = (self._offset + len(pcm)) % len(self._noise)
        noisy = np.clip(pcm.astype(np.float32) + noise, -32768, 32767).astype(np.int16)
        if self._streaming:
            self._decoder.process_raw(noisy.tobytes(), full_utt=False)
        else:
            self._held.append(noisy)
        self.samples_decoded += len(pcm)

    def abandon(self) -> None:
        if self._open and self._streaming:
            self._decoder.end_utt()
        self._held = []
        self._open = False

    def finish(self) -> Heard:
        if not self._open:
            return Heard("", ())
        self._open = False
        if not self._streaming:
            self._decoder.start_utt()
            audio = np.concatenate(self._held) if self._held else np.zeros(0, dtype=np.int16)
            self._held = []
            self._decoder.process_raw(audio.tobytes(), full_utt=True)
        self._decoder.end_utt()
        return self._heard()

    def partial(self) -> Heard:
        """The best guess so far of the open utterance (its words may still change)."""
        return self._heard() if self._open and self._streaming else Heard("", ())

    def _heard(self) -> Heard:
        hyp = self._decoder.hyp()
        words = tuple(
            (str(seg.word).split("(", 1)[0], seg.start_frame * FRAME_S, (seg.end_frame + 1) * FRAME_S)
            for seg in self._decoder.seg() or ()  # None before the first word
            if not str(seg.word).startswith(("<", "["))
        )
        return Heard(str(hyp.hypstr) if hyp is not None else "", words)
