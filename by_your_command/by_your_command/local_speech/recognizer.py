"""Offline recognition of one whole utterance: a command, a wake/sleep/stop phrase, a question, or
nothing (rejected).

The default search (`Search.MOONSHINE`) asks the Moonshine speech model (moonshine.py; its model
ships in the moonshine-cpp wheel) how well each spoken form explains the noise-suppressed
utterance (front_end.py). pocketsphinx is a second opinion: it forced-aligns Moonshine's leading
meanings to the audio and its grammar pass names the meaning it heard, which reranks them
(rescoring.py), and the reranked best is accepted when the evidence of both models is strong
enough (acceptance.py: looser limits for a noisy utterance, a stricter verified path for a
reverberant one); failing that, Moonshine's best form if a free transcription would have written
almost exactly that form, or pocketsphinx's verified form if Moonshine finds it near enough.
Without the model it falls back to pocketsphinx alone (`Search.VERIFIED`, below).

pocketsphinx (its en-us model ships in the wheel) decodes twice, with two models generated from
the command vocabulary (language_model.py): a JSGF grammar of the spoken forms, which is accurate
but forces every utterance into its nearest form, and a filler model where the forms compete with a
loop of everyday words. Only a hypothesis that is exactly one spoken form in the grammar AND means
the same in the filler model is accepted; chat decodes as filler words and is rejected (see
bench/offline_experiments.md for the measurements behind this choice).

Input is untrusted: odd byte counts, unsupported rates, too short or too long utterances and
silence are rejected before decoding (a counted reason, never an exception), which also bounds
the decode time by max_utterance_s.
"""

from __future__ import annotations

import copy
import enum
import logging
import math
import os
import re
import tempfile
import threading
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from by_your_command.audio.pcm import Int16Array, resample
from by_your_command.commands.vocabulary import Vocabulary, load_vocabulary
from by_your_command.local_speech.acceptance import Acceptance, AcceptLimits
from by_your_command.local_speech.asking import Verbs, not_asked_for
from by_your_command.local_speech.filler_words import FILLER_WORDS
from by_your_command.local_speech.front_end import Cleaned, NoiseSuppression, fall_time_ms, suppress_noise
from by_your_command.local_speech.language_model import GarbageWeights, arpa_model, jsgf_grammar
from by_your_command.local_speech.moonshine import (
    FormScore,
    ModelUnavailableError,
    MoonshineConfig,
    MoonshineScorer,
)
from by_your_command.local_speech.rescoring import Alignment, Candidate, Rescored, leading, rescore
from by_your_command.local_speech.spoken import (
    RecognitionKind,
    SpokenForm,
    SpokenVocabularyConfig,
    build_spoken_forms,
    pronounceable,
    said_again,
    written_forms,
)
from by_your_command.local_speech.tool_phrases import NOT_IN_DICTIONARY, TAKEN, ToolPhrase, warn_left_out

log = logging.getLogger(__name__)

DECODER_RATE = 16000  # the en-us acoustic model's rate (and Moonshine's)
MIN_INPUT_RATE, MAX_INPUT_RATE = 8000, 48000
GRAMMAR_SEARCH, FILLER_SEARCH = "grammar", "filler"
# pocketsphinx keeps acoustic scores scaled down by 2**10 (SENSCR_SHIFT): this brings the log of a
# hypothesis score back to natural-log units.
SCORE_SCALE = 1024.0


class Rejection(str, enum.Enum):
    """Why an utterance produced nothing (counted per reason)."""

    ODD_BYTES = "odd number of bytes: not 16-bit PCM"
    BAD_RATE = "unsupported sample rate"
    TOO_SHORT = "too short"
    TOO_LONG = "too long: not decoded"
    SILENCE = "silence"
    NOT_IN_GRAMMAR = "not a command, phrase or question"
    UNCONFIRMED = "the filler model heard something else"
    NOT_A_FORM = "the speech model heard something else"


class Search(str, enum.Enum):
    # Moonshine picks the form (the grammar's form when Moonshine nearly agrees); falls back to
    # VERIFIED when the model is not installed.
    MOONSHINE = "moonshine"
    # The grammar proposes, the filler model must agree (same meaning): never acts on chat.
    VERIFIED = "verified"
    FILLER_LM = "filler_lm"  # forms + garbage loop of filler words only (rejects most chat)
    BARE_GRAMMAR = "bare_grammar"  # JSGF of the forms only: the baseline that forces chat into commands


@dataclass(frozen=True)
class RecognizerConfig:
    commands_file: str = ""  # empty: the installed config/commands.yaml
    spoken: SpokenVocabularyConfig = field(default_factory=SpokenVocabularyConfig)
    search: Search = Search.MOONSHINE
    moonshine: MoonshineConfig = field(default_factory=MoonshineConfig)
    noise_suppression: NoiseSuppression = field(default_factory=NoiseSuppression)  # before Moonshine
    acceptance: Acceptance = field(default_factory=Acceptance)  # when a form is taken (acceptance.py)
    garbage: GarbageWeights = field(default_factory=GarbageWeights)
    language_weight: float = 6.5  # pocketsphinx `lw`: how much the model counts against the acoustics
    filler_words: tuple[str, ...] = FILLER_WORDS
    max_utterance_s: float = 8.0  # longer input is rejected unread: commands are short
    min_utterance_s: float = 0.15
    silence_dbfs: float = -55.0  # quieter (RMS) input is silence, not decoded
    # Digital silence makes pocketsphinx drop the last word (measured): faint noise under the whole
    # utterance and a short noise tail after it.
    dither_rms: float = 10.0
    noise_tail_s: float = 0.3
    noise_tail_rms: float = 100.0

    def __post_init__(self) -> None:
        if not 0.0 < self.min_utterance_s < self.max_utterance_s:
            raise ValueError("need 0 < min_utterance_s < max_utterance_s")
        if self.language_weight <= 0:
            raise ValueError("language_weight must be positive")
        if self.dither_rms < 0 or self.noise_tail_rms < 0 or self.noise_tail_s < 0:
            raise ValueError("dither and noise tail must not be negative")


@dataclass(frozen=True)
class Recognition:
    kind: RecognitionKind
    text: str  # what the decoder heard (the spoken form, or its hypothesis when rejected)
    canonical: str  # command normal form, phrase command or question id; "" when rejected
    confidence: float  # posterior of the hypothesis (0..1); 0 when rejected
    reason: str = ""  # why it was rejected


@dataclass
class RecognizerStats:
    decoded: int = 0
    by_kind: Counter[str] = field(default_factory=Counter)
    rejections: Counter[str] = field(default_factory=Counter)


@dataclass(frozen=True)
class Evidence:
    """What Moonshine and pocketsphinx say about one utterance, before any limit is applied."""

    snr_db: float  # the loud frames over the background (front_end.Cleaned)
    forms: list[FormScore]  # Moonshine's finished forms, best first
    free_text: str  # Moonshine's own transcript
    grammar_text: str  # pocketsphinx's grammar pass ("" when it heard nothing, or was not run)
    candidates: list[Candidate]  # the leading meanings with pocketsphinx's evidence (rescoring.py)
    fall_ms: float = 0.0  # how slowly its sounds die away: reverberation (front_end.fall_time_ms)


_STOP = (RecognitionKind.PHRASE, "stop")  # the phrase that outranks everything
# Words of a tool phrase that are no evidence it was said: "the" written alone is no "go to the kitchen".
_FUNCTION_WORDS = frozenset(
    ("a", "an", "the", "to", "of", "in", "on", "at", "my", "your", "and", "for", "me")
)


def _phrase_capped(kind: RecognitionKind, regret: float, limits: AcceptLimits) -> float:
    """A regret limit, lowered to phrase_max_regret for the short wake/sleep/stop phrases."""
    return min(regret, limits.phrase_max_regret) if kind is RecognitionKind.PHRASE else regret


def _holds(longer: list[str], words: list[str]) -> bool:
    """Whether `longer` has more words than `words` and all of them, in order."""
    remaining = iter(longer)
    return len(longer) > len(words) and all(word in remaining for word in words)


def _words(text: str) -> list[str]:
    """A transcript's words, lower case, without punctuation ("Left, left." -> left, left; "..."
    -> none)."""
    return re.findall(r"[^\W_]+(?:'[^\W_]+)*", text.lower())


def _rejected(reason: Rejection, text: str = "") -> Recognition:
    return Recognition(RecognitionKind.REJECTED, text, "", 0.0, reason.value)


class OfflineRecognizer:
    """Decodes whole utterances; thread-safe (one decoder, one utterance at a time)."""

    def __init__(
        self,
        config: RecognizerConfig | None = None,
        vocabulary: Vocabulary | None = None,
        tools: Sequence[ToolPhrase] = (),
    ) -> None:
        self.config = config or RecognizerConfig()
        self.vocabulary = vocabulary or load_vocabulary(self.config.commands_file or None)
        # Imported here: the rest of the package works without the 38 MB wheel.
        import pocketsphinx  # type: ignore[import-untyped]

        self._pocketsphinx = pocketsphinx
        self._pronunciations = _read_dictionary(pocketsphinx.Config()["dict"])
        missing = [word for word in self.config.filler_words if word not in self._pronunciations]
        if missing:
            raise ValueError(f"filler words not in the pronunciation dictionary: {missing}")
        self.search = self.config.search  # what runs: MOONSHINE falls back to VERIFIED without it
        self._scorer: MoonshineScorer | None = None
        self._build(tools)

    def with_tools(self, tools: Sequence[ToolPhrase]) -> OfflineRecognizer:
        """A recognizer that also hears these tool phrases (and no others), sharing this one's
        loaded parts: the pronunciation dictionary and the Moonshine model. Only the forms, the
        small pocketsphinx decoder and the form trie are built (milliseconds, not the seconds of a
        load); this one is left as it is (a decode on it may still run)."""
        other = copy.copy(self)
        other._build(tools)
        return other

    def _build(self, tools: Sequence[ToolPhrase]) -> None:
        self.stats = RecognizerStats()
        self._lock = threading.Lock()
        pronunciations = self._pronunciations
        known = pronunciations.__contains__
        self.tools, self.tools_left_out = self._hearable(tools, known)
        named = build_spoken_forms(self.vocabulary, self.config.spoken, self.tools)
        meanings = {form.words: form.canonical for form in named}
        taken = [phrase.words for phrase in self.tools if meanings.get(phrase.words) != phrase.canonical]
        if taken:
            self.tools_left_out[TAKEN] += len(taken)
            warn_left_out(TAKEN, taken)
            self.tools = tuple(phrase for phrase in self.tools if phrase.words not in set(taken))
        self.forms: list[SpokenForm] = pronounceable(named, known)
        written = [written_forms(a.words, b.words) for a, b in zip(named, self.forms, strict=True)]
        # Typed text is matched against the forms as declared, before they were made pronounceable.
        self.tool_forms = [form for form in named if form.kind is RecognitionKind.TOOL]
        # Wake, sleep and stop said again are still that phrase ("stop, stop!"); a command said
        # twice might mean twice, and is left to be said once.
        self._written = [
            said_again(ways) if form.kind is RecognitionKind.PHRASE else ways
            for form, ways in zip(self.forms, written, strict=True)
        ]
        # pocketsphinx's passes know the plain forms only (_load_searches).
        self._pocketsphinx_forms = {
            form.words: form for form in self.forms if not (form.polite or form.extra)
        }
        spoken = self.config.spoken
        openings = set(" ".join(spoken.polite_openings).split())
        # What Moonshine writes of a polite opening or closing: "Can you" also for "could you".
        self._polite_words = frozenset(" ".join(spoken.polite_openings + spoken.polite_closings).split())
        self._politeness_cues = frozenset(
            [opening.split()[0] for opening in spoken.polite_openings if opening.split()]
            + " ".join(spoken.polite_closings).split()
        )
        self._verbs = Verbs(  # every command's and phrase's first word after a polite opening
            frozenset(
                next((word for word in form.words.split() if word not in openings), form.words.split()[0])
                for form in self.forms
                if form.kind is not RecognitionKind.QUESTION
            )
        )
        self._words_by_meaning: dict[tuple[RecognitionKind, str], set[str]] = defaultdict(set)
        for form in self.forms:
            self._words_by_meaning[(form.kind, form.canonical)].update(form.words.split())
        # The decoder gets a dictionary of only the words it can hear: with the shipped 126k-word
        # dictionary, building the filler model's search took 0.6-6 s (most of the load time);
        # with these few hundred words it takes milliseconds, and decodes the same.
        needed = {word for form in self.forms for word in form.words.split()} | set(self.config.filler_words)
        self._decoder = _decoder_with(
            self._pocketsphinx,
            "".join(line for word in sorted(needed) for line in pronunciations[word]),
            self.config.language_weight,
        )
        if self._scorer is not None:  # the model is loaded: only the forms' trie is new
            self._scorer = self._scorer.with_texts(self._written)
        elif self.search is Search.MOONSHINE:
            try:
                self._scorer = MoonshineScorer(self._written, self.config.moonshine)
            except ModelUnavailableError as error:
                log.warning("offline recognition without the Moonshine model (%s): pocketsphinx only", error)
                self.search = Search.VERIFIED
        self._load_searches()

    @staticmethod
    def _hearable(
        tools: Sequence[ToolPhrase], known: Callable[[str], bool]
    ) -> tuple[tuple[ToolPhrase, ...], Counter[str]]:
        """The tool phrases whose every word pocketsphinx can pronounce (a word it does not know
        may be two it does: spoken.pronounceable); the others are named in a warning."""
        kept, unknown = [], []
        for phrase in tools:
            try:
                pronounceable([SpokenForm(phrase.words, RecognitionKind.TOOL, phrase.canonical)], known)
            except ValueError as error:
                unknown.append(f"{phrase.words} ({error})")
                continue
            kept.append(phrase)
        left_out: Counter[str] = Counter()
        if unknown:
            left_out[NOT_IN_DICTIONARY] = len(unknown)
            warn_left_out(NOT_IN_DICTIONARY, unknown)
        return tuple(kept), left_out

    def _load_searches(self) -> None:
        # pocketsphinx's passes know the plain forms only: optional polite words in its grammar
        # made the search three times slower and it heard them in the noise before "turn left".
        # An extra form is no name and bearing, and its words may sound like anything: both passes
        # heard "turn around" in people's single "down" and "nine". Moonshine scores those forms.
        words = list(self._pocketsphinx_forms)
        if self.search is not Search.FILLER_LM:
            self._decoder.add_jsgf_string(GRAMMAR_SEARCH, jsgf_grammar(words))
        if self.search is Search.BARE_GRAMMAR:
            return
        model = arpa_model(words, self.config.filler_words, self.config.garbage)
        handle, path = tempfile.mkstemp(suffix=".arpa", prefix="byc-offline-")
        try:
            with os.fdopen(handle, "w", encoding="ascii") as file:
                file.write(model)
            self._decoder.add_lm_file(FILLER_SEARCH, path)
        finally:
            os.unlink(path)

    def recognize(self, pcm: bytes, sample_rate: int) -> Recognition:
        """One whole utterance of mono int16 little-endian PCM; never raises on bad audio."""
        result = self._recognize(pcm, sample_rate)
        self.stats.by_kind[result.kind.value] += 1
        if result.kind is RecognitionKind.REJECTED:
            self.stats.rejections[result.reason] += 1
        return result

    def _recognize(self, pcm: bytes, sample_rate: int) -> Recognition:
        config = self.config
        if len(pcm) % 2:
            return _rejected(Rejection.ODD_BYTES)
        if not MIN_INPUT_RATE <= sample_rate <= MAX_INPUT_RATE:
            return _rejected(Rejection.BAD_RATE)
        seconds = len(pcm) / 2 / sample_rate
        if seconds > config.max_utterance_s:
            return _rejected(Rejection.TOO_LONG)
        if seconds < config.min_utterance_s:
            return _rejected(Rejection.TOO_SHORT)
        samples: Int16Array = np.frombuffer(pcm, dtype="<i2").astype(np.int16)
        if _rms_dbfs(samples) < config.silence_dbfs:
            return _rejected(Rejection.SILENCE)
        samples = resample(samples, sample_rate, DECODER_RATE)
        if self._scorer is not None:
            return self._moonshine(samples)
        audio = self._prepared(samples)
        first = FILLER_SEARCH if self.search is Search.FILLER_LM else GRAMMAR_SEARCH
        hypothesis, confidence = self._decode(audio, first)
        form = self._pocketsphinx_forms.get(hypothesis)
        if form is None:
            return _rejected(Rejection.NOT_IN_GRAMMAR, hypothesis)
        if self.search is Search.VERIFIED:
            # The grammar always finds its nearest form; only when the filler model, free to
            # hear any words, hears the same meaning is it a command.
            check, confidence = self._decode(audio, FILLER_SEARCH)
            confirmed = self._pocketsphinx_forms.get(check)
            if confirmed is None or confirmed.canonical != form.canonical:
                return _rejected(Rejection.UNCONFIRMED, f"{hypothesis} / {check}")
        return Recognition(form.kind, form.words, form.canonical, confidence)

    def _moonshine(self, samples: Int16Array) -> Recognition:
        """Moonshine's leading meanings reranked with pocketsphinx's evidence; the reranked best if
        the evidence for it holds, else Moonshine's best form if it is (nearly) what Moonshine
        would write freely, else the pocketsphinx-verified form (acceptance.py, with the noisy or
        reverberant limits when the utterance is so). Confidence exp(-regret)."""
        evidence = self.evidence(samples)
        chosen = self.decide(evidence, self.config.acceptance, lambda: self.filler_heard(samples))
        if chosen is None:
            heard = f"heard {evidence.free_text!r}"
            if evidence.forms:
                heard += f", pocketsphinx {evidence.grammar_text!r}"
            return _rejected(Rejection.NOT_A_FORM, heard)
        form = self.forms[chosen.index]
        return Recognition(form.kind, form.words, form.canonical, float(np.exp(-chosen.regret)))

    def evidence(self, samples: Int16Array) -> Evidence:
        """What both models say about one 16 kHz utterance (the Moonshine search): Moonshine's forms
        and, when it found any, pocketsphinx's grammar pass and its alignments of the leading
        meanings."""
        assert self._scorer is not None
        cleaned = self._moonshine_input(samples)
        fall_ms = fall_time_ms(samples, DECODER_RATE)
        with self._lock:
            analysis = self._scorer.analyse(cleaned.audio)
            self.stats.decoded += 1
        if not analysis.forms:
            return Evidence(cleaned.snr_db, [], analysis.free.text, "", [], fall_ms)
        audio = self._prepared(samples)
        grammar, _ = self._decode(audio, GRAMMAR_SEARCH)
        candidates = self._candidates(audio, analysis.forms, self._pocketsphinx_forms.get(grammar))
        return Evidence(cleaned.snr_db, analysis.forms, analysis.free.text, grammar, candidates, fall_ms)

    def filler_heard(self, samples: Int16Array) -> str:
        """What pocketsphinx's filler model hears in a 16 kHz utterance ("" for nothing)."""
        return self._decode(self._prepared(samples), FILLER_SEARCH)[0]

    def decide(
        self, evidence: Evidence, acceptance: Acceptance, filler_heard: Callable[[], str]
    ) -> FormScore | None:
        """The form taken on this evidence (acceptance.py), or None. `filler_heard`: what
        pocketsphinx's filler pass hears, asked only when the other paths fail."""
        forms = evidence.forms
        if not forms:
            return None
        limits = acceptance.limits(evidence.snr_db, evidence.fall_ms)
        grammar = self._pocketsphinx_forms.get(evidence.grammar_text)
        # Even a form Moonshine is sure of gives way to another meaning the reranking puts first
        # with enough evidence: some voices' "move full right" is "Move forward" at regret 0.
        reranked = rescore(evidence.candidates, acceptance.rerank)
        chosen = self._rescored_choice(reranked, grammar, limits, evidence.free_text)
        if chosen is not None and self._overrules_written_form(chosen, evidence, grammar, limits):
            chosen = None  # Moonshine's form, written word for word, is taken below
        if chosen is None and forms[0].regret <= limits.as_written_regret:
            chosen = forms[0]
        if chosen is None and grammar is not None:
            confirmed = self._pocketsphinx_forms.get(filler_heard())
            if confirmed is not None and confirmed.canonical == grammar.canonical:
                meaning = (grammar.kind, grammar.canonical)
                same = [
                    s
                    for s in forms
                    if self._meaning(s) == meaning and s.end_regret <= limits.cut_short_regret
                ]
                limit = _phrase_capped(grammar.kind, limits.verified_regret, limits)
                if same and min(s.regret for s in same) <= limit:
                    verified = min(same, key=lambda s: s.regret)
                    per_word = limits.verified_off_transcript_per_word
                    if not self._far_from_transcript(verified, evidence.free_text, per_word):
                        chosen = verified
        if chosen is None:
            return None
        noisy = evidence.snr_db < acceptance.noisy_below_snr_db
        if chosen.regret > limits.as_written_regret and (
            self._written_in_part(chosen, evidence.free_text)
            or self._not_asked_for(chosen, evidence.free_text, noisy)
        ):
            return None
        if self._longer_form_as_likely(chosen, forms, limits):
            return None
        if self._moves_base_unheard(chosen, evidence.free_text, grammar, acceptance):
            return None
        if self.forms[chosen.index].kind is RecognitionKind.QUESTION:
            return self._question_or_stop(chosen, forms, grammar, limits, acceptance)
        return chosen

    def _overrules_written_form(
        self, chosen: FormScore, evidence: Evidence, grammar: SpokenForm | None, limits: AcceptLimits
    ) -> bool:
        """Whether the reranked choice is another meaning than a form Moonshine wrote word for word,
        on pocketsphinx's alignments alone: "Please look up." was taken as `lookout`. Only
        pocketsphinx's grammar hearing the other meaning overrules such a transcript (some voices'
        "move full right" is "Move forward" to Moonshine, and the grammar heard "move full right")."""
        written = evidence.forms[0]
        if written.end_regret > limits.cut_short_regret or self._meaning(chosen) == self._meaning(written):
            return False
        words = tuple(_words(evidence.free_text))
        if not words or words not in {tuple(_words(way)) for way in self._written[written.index]}:
            return False
        return grammar is None or (grammar.kind, grammar.canonical) != self._meaning(chosen)

    def _moves_base_unheard(
        self, score: FormScore, free_text: str, grammar: SpokenForm | None, acceptance: Acceptance
    ) -> bool:
        """Whether a command that drives the base has no positive evidence: Moonshine wrote none of
        its command's words and pocketsphinx's grammar heard another meaning or nothing. A wrong
        turn cannot be taken back; a command turned away is said again."""
        form = self.forms[score.index]
        base = form.canonical.partition("@")[0]
        # A robot tool may drive the base too ("go to the kitchen"), and nothing here says which
        # does: every tool call needs the same positive evidence, from a word that carries meaning.
        tool = form.kind is RecognitionKind.TOOL
        if not tool and (
            form.kind is not RecognitionKind.COMMAND or base not in acceptance.base_moving_commands
        ):
            return False
        if grammar is not None and (grammar.kind, grammar.canonical) == self._meaning(score):
            return False
        command_words = set(form.words.split()) - self._polite_words - (_FUNCTION_WORDS if tool else set())
        return not command_words & set(_words(free_text))

    def _question_or_stop(
        self,
        question: FormScore,
        forms: list[FormScore],
        grammar: SpokenForm | None,
        limits: AcceptLimits,
        acceptance: Acceptance,
    ) -> FormScore | None:
        """The question, unless a stop phrase may have been said: "halt" was answered with what the
        robot can do (heard as "help"). Stop outranks everything: pocketsphinx's grammar heard it,
        or Moonshine found it (ending where the model ends) within stop_over_question_regret of the
        question and near enough to be heard (phrase_max_regret), and it is taken. Nearly as likely but
        further than that (chat: "how old are you" put "stop" at 9.9, the question at 11.4), neither
        is."""
        stops = [s for s in forms if self._meaning(s) == _STOP and s.end_regret <= limits.cut_short_regret]
        if grammar is not None and (grammar.kind, grammar.canonical) == _STOP and stops:
            return min(stops, key=lambda score: score.regret)
        near = [s for s in stops if s.regret <= question.regret + acceptance.stop_over_question_regret]
        if not near:
            return question
        best = min(near, key=lambda score: score.regret)
        return best if best.regret <= limits.phrase_max_regret else None

    def _far_from_transcript(self, score: FormScore, free_text: str, per_word: float) -> bool:
        """Whether Moonshine wrote words of its own and the form is more than `per_word` regret per
        word of its command from them (a polite form's polite words, written as said, cost no
        regret and earn no allowance). An empty transcript is no evidence against the form:
        Moonshine often writes nothing for espeak's commands."""
        form = self.forms[score.index]
        command_words = len(form.words.split()) - form.polite_words
        return bool(_words(free_text)) and score.regret > per_word * command_words

    def _written_politely(self, score: FormScore, free_text: str, limits: AcceptLimits) -> bool:
        """Whether Moonshine wrote a polite word and the polite form is near what it wrote."""
        written = set(_words(free_text))
        return bool(written & self._politeness_cues) and not self._far_from_transcript(
            score, free_text, limits.off_transcript_per_word
        )

    def _written_in_part(self, score: FormScore, free_text: str) -> bool:
        """Whether Moonshine wrote some of the form's words and nothing else: "Left" for "reach
        left", "Up." for "look up". A word said alone; the rest of the form was not heard."""
        written = set(_words(free_text))
        return bool(written) and written < set(self.forms[score.index].words.split())

    def _not_asked_for(self, score: FormScore, free_text: str, noisy: bool) -> bool:
        """Whether Moonshine wrote a command's words in a sentence that does not ask for it: "I
        turned left", "don't look up", "if you turn left" (asking.py). A question is answered, not
        acted on: not judged so."""
        form = self.forms[score.index]
        if form.kind is RecognitionKind.QUESTION:
            return False
        same_meaning = self._words_by_meaning[self._meaning(score)]
        return not_asked_for(_words(free_text), form.words.split(), self._verbs, same_meaning, noisy)

    def _longer_form_as_likely(self, chosen: FormScore, forms: list[FormScore], limits: AcceptLimits) -> bool:
        """Whether Moonshine finds, nearly as likely as `chosen`, a form of another meaning holding
        all its words and more: "reach to the back right" against "reach to the right", one short
        word apart, which reverberation smears (acceptance.py)."""
        words = self.forms[chosen.index].words.split()
        meaning = self._meaning(chosen)
        return any(
            other.regret <= chosen.regret + limits.longer_form_ambiguity_regret
            and other.end_regret <= limits.cut_short_regret
            and self._meaning(other) != meaning
            and _holds(self.forms[other.index].words.split(), words)
            for other in forms
        )

    def _candidates(
        self, audio: bytes, forms: list[FormScore], grammar: SpokenForm | None
    ) -> list[Candidate]:
        """Moonshine's leading meanings with pocketsphinx's evidence about each (`grammar`: the
        form its grammar pass heard)."""
        heard = None if grammar is None else (grammar.kind, grammar.canonical)
        candidates = []
        for score in leading(forms, self._meaning, self.config.acceptance.rescore_meanings):
            words = self.forms[score.index].words
            alignment = self._align(audio, words)
            candidates.append(Candidate(score, alignment, len(words.split()), self._meaning(score) == heard))
        return candidates

    def _rescored_choice(
        self, rescored: list[Rescored], grammar: SpokenForm | None, limits: AcceptLimits, free_text: str
    ) -> FormScore | None:
        """The reranked best form if the evidence for it is strong enough (acceptance.py);
        `free_text`: what Moonshine wrote freely."""
        if not rescored:
            return None
        best = rescored[0]
        score = best.score
        if score.end_regret > limits.cut_short_regret:  # the model heard more words after it
            return None
        form = self.forms[score.index]
        agrees = grammar is not None and (grammar.kind, grammar.canonical) == self._meaning(score)
        if form.words not in self._pocketsphinx_forms:
            # pocketsphinx does not know the polite words or the extra forms: on Moonshine's word,
            # or a polite form Moonshine wrote politely with more evidence for its command (not
            # on the alignment path; acceptance.py).
            if score.regret <= limits.moonshine_alone_regret:
                return score
            if not form.polite or form.extra or score.regret > limits.polite_written_regret:
                return None
            if not self._written_politely(score, free_text, limits):
                return None
            reranked = limits.polite_on_rerank_score and best.combined >= limits.min_rerank_score
            return score if agrees or reranked else None
        kind = form.kind
        # A phrase on Moonshine's word alone only if it is nearly what Moonshine wrote: in noise
        # "what's up" is "wake up" at regret 1.1.
        near = limits.as_written_regret if kind is RecognitionKind.PHRASE else limits.moonshine_alone_regret
        if score.regret <= near:
            return score
        # Moonshine wrote other words ("What's up?", where pocketsphinx's grammar, which must
        # name some form, heard "look up" at regret 8.6): a short form must then be near them
        # word for word. An empty transcript is no evidence against the form.
        if self._far_from_transcript(score, free_text, limits.off_transcript_per_word):
            return None
        if (
            (agrees and score.regret <= _phrase_capped(kind, limits.grammar_agrees_regret, limits))
            or (
                kind is not RecognitionKind.PHRASE
                and score.regret <= limits.alignment_path_regret
                and best.alignment.per_frame >= limits.alignment_path_min_per_frame
                and best.margin >= limits.alignment_path_min_margin
            )
            or (kind is not RecognitionKind.PHRASE and best.combined >= limits.min_rerank_score)
        ):
            return score
        return None

    def _meaning(self, score: FormScore) -> tuple[RecognitionKind, str]:
        form = self.forms[score.index]
        return form.kind, form.canonical

    def _moonshine_input(self, samples: Int16Array) -> Cleaned:
        """Moonshine's input: float audio, noise suppressed (front_end.py), and its SNR."""
        return suppress_noise(samples.astype(np.float32) / 32768.0, self.config.noise_suppression)

    def _prepared(self, samples: Int16Array) -> bytes:
        config = self.config
        rng = np.random.default_rng(len(samples))  # the same input decodes the same way
        dithered = samples + rng.normal(0.0, config.dither_rms, len(samples))
        tail = rng.normal(0.0, config.noise_tail_rms, int(config.noise_tail_s * DECODER_RATE))
        audio = np.clip(np.concatenate([dithered, tail]), -32768, 32767)
        return bytes(np.rint(audio).astype("<i2").tobytes())

    def _decode(self, audio: bytes, search: str) -> tuple[str, float]:
        with self._lock:
            self._decoder.activate_search(search)
            hypothesis = self._run(audio)
            if hypothesis is None:
                return "", 0.0
            confidence = float(self._decoder.get_prob())
        return " ".join(str(hypothesis.hypstr).split()), min(1.0, max(0.0, confidence))

    def _align(self, audio: bytes, words: str) -> Alignment | None:
        """pocketsphinx's forced alignment of `words` to the audio; None if they do not fit."""
        with self._lock:
            self._decoder.set_align_text(words)
            hypothesis = self._run(audio)
            frames = int(self._decoder.n_frames())
        if hypothesis is None or not hypothesis.score > 0.0:
            return None
        return Alignment(SCORE_SCALE * math.log(hypothesis.score), frames)

    def _run(self, audio: bytes) -> Any:
        """One utterance through the decoder's current search; its hypothesis or None. The caller
        holds the lock."""
        decoder = self._decoder
        decoder.start_utt()
        decoder.process_raw(audio, False, True)
        decoder.end_utt()
        self.stats.decoded += 1
        return decoder.hyp()


def _read_dictionary(path: str) -> dict[str, list[str]]:
    """The pronunciation dictionary's lines by word ("the" -> ["the DH AH", "the(2) DH IY"])."""
    lines: dict[str, list[str]] = {}
    with open(path, encoding="utf-8") as file:
        for line in file:
            if line.strip():
                lines.setdefault(line.split(None, 1)[0].split("(", 1)[0], []).append(line.rstrip("\n") + "\n")
    return lines


def _decoder_with(pocketsphinx: Any, dictionary: str, language_weight: float) -> Any:
    """A pocketsphinx decoder (the wheel's en-us model) with this dictionary text."""
    handle, path = tempfile.mkstemp(suffix=".dict", prefix="byc-offline-")
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as file:
            file.write(dictionary)
        return pocketsphinx.Decoder(lm=None, dict=path, lw=language_weight, loglevel="FATAL")
    finally:
        os.unlink(path)


def _rms_dbfs(samples: Int16Array) -> float:
    power = float(np.mean(np.square(samples, dtype=np.float64))) if len(samples) else 0.0
    return 10.0 * float(np.log10(max(power, 1e-12) / 32768.0**2))
