"""When the recognizer takes a form: the regret limits of each accept path, and which set of them
holds for an utterance (noisy audio gets its own).

Regret (moonshine.py): how far, in log probability summed over tokens, a form is from what
Moonshine would have written freely; its end regret is the part paid for ending there (the model
heard more words). Moonshine's first `rescore_meanings` meanings are reranked by a weighted sum of
both models' evidence (`rerank`, rescoring.py), and the reranked best is accepted if it ends where
the model ends (end regret at most end_regret) and
- its regret is at most near_regret;
- or at most agree_regret, and the pocketsphinx grammar heard the same meaning;
- or at most aligned_regret, it aligns at least aligned_per_frame (nats per 10 ms frame) and beats
  the next meaning by `margin` (in reranking score);
- or its reranking score, which weighs all the evidence, is at least evidence_score;
and on these last three paths, when Moonshine wrote words of its own, its regret is at most
written_regret_per_word per word of the form (a short form is then a word away from what was said:
"What's up?" scores "look up" at 8.6, and pocketsphinx's grammar, which must name some form, heard
"look up"; an empty transcript is no evidence against the form).
Failing all that, Moonshine's best form is taken up to accept_regret, or else the
pocketsphinx-verified form (grammar and filler model agree) if Moonshine finds that meaning within
confirm_regret, again ending where the model ends, and, when Moonshine wrote words of its own,
within confirm_written_regret_per_word per word of the form (people recorded saying "up" and
"off": Moonshine wrote "Up." and "Office.", both pocketsphinx passes heard "bumper" and "stop").
Wake/sleep/stop phrases are one or two words, so chat holding one ("I'm freezing", "what's up",
"sleep well") is a word or two away from them: a phrase is taken on Moonshine's word alone only up
to accept_regret (nearly what it wrote freely), with pocketsphinx agreeing only up to
phrase_regret, and never on the alignment or the reranking score alone. A polite form ("please
follow me") is taken on Moonshine's word up to near_regret: pocketsphinx does not know the
polite words. Beyond that only up to polite_regret, when Moonshine wrote a polite word ("please",
"can", "could"; in noise the closing "please" is often "clean") and the form is within
written_regret_per_word per word of the command it wraps, and then when pocketsphinx's grammar
heard that command or the reranking score reaches evidence_score; the latter not in noise, where
Moonshine makes "please" of any "pl..." ("play some music" was taken as "please follow me").
Whatever the path, beyond accept_regret a form is not taken when Moonshine wrote some of its words
and nothing else ("Left" for "reach left", "Up." for "look up": a word said alone, the rest of the
form unheard), nor when Moonshine finds a longer form of another meaning that holds all its words,
within longer_form_regret of it ("reach to the back right" for "reach to the right"): the two
differ by a word Moonshine may or may not have heard, and in a reverberant room short words such
as "back" are smeared into the next ("Reach to the band ride."): taken, the shorter form is often
a wrong bearing.
Three rules have the last word. The reranking does not overrule a form Moonshine wrote word for
word ("Please look up." was taken as `lookout`) unless pocketsphinx's grammar heard the other
meaning. A command that drives the base (`moves_base`) needs positive evidence: Moonshine wrote a
word of it, or pocketsphinx's grammar heard it. And a question gives way to a stop phrase that may
have been said (`stop_over_question_regret`): stop outranks everything.

Noise raises every regret, the right form's and chat's alike: Moonshine is less sure of every
token. Limits that keep all chat out of clean speech therefore turn away commands in noise that
looser limits would take without taking chat, so an utterance whose SNR (front_end.py) is below
`noisy_below_snr_db` is judged by `noisy`. Reverberation has the opposite effect on chat: across
a room pocketsphinx hears worse still than Moonshine, and its passes agree with Moonshine on forms
that were never said ("are you a robot" verified as "can you move forward" at regret 10). A quiet
utterance whose sounds die away slowly (front_end.fall_time_ms at least `reverberant_from_fall_ms`)
is judged by `reverberant`: the clean limits with a stricter verified path. All sets were tuned on
other espeak voices than the benchmark's (docs/offline.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from by_your_command.offline.rescoring import RerankWeights


@dataclass(frozen=True)
class AcceptLimits:
    accept_regret: float = 1.0
    end_regret: float = 0.25
    near_regret: float = 3.0
    agree_regret: float = 9.0
    aligned_regret: float = 6.0
    aligned_per_frame: float = -1.6
    margin: float = 1.0
    evidence_score: float = -4.5  # a reranking score (rescoring.py) this high is evidence enough
    confirm_regret: float = 12.0
    phrase_regret: float = 6.0
    # A polite form beyond near_regret: taken up to this when Moonshine wrote a polite word ("Can
    # you look out to the light?") and pocketsphinx's grammar heard its command or, where
    # polite_on_reranking, the reranking score reaches evidence_score.
    polite_regret: float = 9.0
    polite_on_reranking: bool = True
    # Beyond near_regret, when Moonshine freely wrote words of its own: at most this regret per
    # word of the form (a short form is then a word away from what was said).
    written_regret_per_word: float = 3.5
    # The same on the verified path (pocketsphinx's two passes agree), looser: there Moonshine
    # often writes other words for espeak's commands ("Lume my hand" for "move ahead").
    confirm_written_regret_per_word: float = 5.0
    # A longer form of another meaning holding all the form's words, this near in regret, makes
    # the form ambiguous: a word more or less ("reach to the (back) right").
    longer_form_regret: float = 5.0

    def __post_init__(self) -> None:
        limits = (
            self.near_regret,
            self.agree_regret,
            self.aligned_regret,
            self.confirm_regret,
            self.phrase_regret,
            self.polite_regret,
        )
        values = (
            self.accept_regret,
            *limits,
            self.end_regret,
            self.margin,
            self.aligned_per_frame,
            self.evidence_score,
            self.written_regret_per_word,
            self.confirm_written_regret_per_word,
            self.longer_form_regret,
        )
        if not all(math.isfinite(value) for value in values):
            raise ValueError("the regret limits and margins must be finite")
        if not 0.0 <= self.accept_regret <= min(limits):
            raise ValueError(
                "need 0 <= accept_regret <= the near, agree, aligned, confirm, phrase and polite regrets"
            )
        written = (self.written_regret_per_word, self.confirm_written_regret_per_word)
        if min(self.end_regret, self.margin, *written, self.longer_form_regret) < 0:
            raise ValueError(
                "end_regret, margin, the written regrets per word and longer_form_regret must not be negative"
            )


def _noisy_default() -> AcceptLimits:
    """Looser where Moonshine and pocketsphinx's grammar agree and on the alignment path, stricter
    on Moonshine's word alone (the noise suppression makes it surer of chat too: "move along" as
    "move ahead") and for polite forms. The verified path keeps the clean limit: up to 16 it took 4
    of 2376 tuning chat lines in white and pink noise at 15 dB for 6 more of 892 commands
    (docs/offline.md)."""
    return AcceptLimits(
        near_regret=2.5,
        agree_regret=13.0,
        aligned_regret=7.0,
        written_regret_per_word=5.0,
        polite_on_reranking=False,
    )


def _reverberant_default() -> AcceptLimits:
    """The clean limits with the verified path at 9: on tuning voices in quiet rooms (RT60 0.3-0.6
    s) it took 4 of 10 chat utterances acted on away for 5 of 1338 commands (docs/offline.md)."""
    return AcceptLimits(confirm_regret=9.0)


@dataclass(frozen=True)
class Acceptance:
    clean: AcceptLimits = field(default_factory=AcceptLimits)
    noisy: AcceptLimits = field(default_factory=_noisy_default)
    # Below this SNR (the loud frames over the background, front_end.Cleaned.snr_db) the noisy
    # limits hold.
    noisy_below_snr_db: float = 20.0
    reverberant: AcceptLimits = field(default_factory=_reverberant_default)
    # A quiet utterance whose steepest falls take this long (front_end.fall_time_ms; straight into
    # a microphone mostly 10-80 ms, in a room with RT60 0.5 s 120-220 ms) is judged by `reverberant`.
    reverberant_from_fall_ms: float = 100.0
    rescore_meanings: int = 4
    rerank: RerankWeights = field(default_factory=RerankWeights)
    # Commands that drive the base: taken only on positive evidence, Moonshine having written a
    # word of the command or pocketsphinx's grammar having heard it ("bumper" in heavy noise was
    # turned around, Moonshine writing nothing and pocketsphinx hearing "bumper").
    moves_base: tuple[str, ...] = ("move", "turn", "follow")
    # A question gives way to a stop phrase pocketsphinx's grammar heard, or that Moonshine finds
    # within this regret of it (taken if within phrase_regret, else neither is): "halt" heard as
    # "help" must stop, not list what the robot does.
    stop_over_question_regret: float = 3.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.noisy_below_snr_db):
            raise ValueError("noisy_below_snr_db must be finite")
        if not 0.0 < self.reverberant_from_fall_ms < math.inf:
            raise ValueError("reverberant_from_fall_ms must be positive and finite")
        if self.rescore_meanings < 1:
            raise ValueError("rescore_meanings must be at least 1")
        if not 0.0 <= self.stop_over_question_regret < math.inf:
            raise ValueError("stop_over_question_regret must be finite and not negative")

    def limits(self, snr_db: float, fall_ms: float) -> AcceptLimits:
        """The limits for an utterance of this SNR and fall time (front_end.py). Noise decides
        first: under it the fall time cannot be seen (its peaks have no room to fall)."""
        if snr_db < self.noisy_below_snr_db:
            return self.noisy
        return self.reverberant if fall_ms >= self.reverberant_from_fall_ms else self.clean
