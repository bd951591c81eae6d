"""When the recognizer takes a form: the limits of each accept path, and which set of them holds
for an utterance (a noisy or reverberant one gets its own). docs/offline.md has them in one table.

Regret (moonshine.py): how far, in log probability summed over tokens, a form is from what
Moonshine would have written freely; its end regret is the part paid for ending there (the model
heard more words). Moonshine's first `rescore_meanings` meanings are reranked by a weighted sum of
both models' evidence (`rerank`, rescoring.py), and the reranked best is taken if it is not cut
short (end regret at most cut_short_regret) and
- its regret is at most moonshine_alone_regret;
- or at most grammar_agrees_regret, and pocketsphinx's grammar heard the same meaning;
- or at most alignment_path_regret, it aligns at least alignment_path_min_per_frame (nats per
  10 ms frame) and beats the next meaning by alignment_path_min_margin (in reranking score);
- or its reranking score, which weighs all the evidence, is at least min_rerank_score;
and on these last three paths, when Moonshine wrote words of its own, its regret is at most
off_transcript_per_word per word of the form (a short form is then a word away from what was said:
"What's up?" scores "look up" at 8.6, and pocketsphinx's grammar, which must name some form, heard
"look up"; an empty transcript is no evidence against the form).
Failing all that, Moonshine's best form is taken up to as_written_regret, or else the
pocketsphinx-verified form (grammar and filler model agree) if Moonshine finds that meaning within
verified_regret, not cut short, and, when Moonshine wrote words of its own, within
verified_off_transcript_per_word per word of the form (people recorded saying "up" and "off":
Moonshine wrote "Up." and "Office.", both pocketsphinx passes heard "bumper" and "stop").
Wake/sleep/stop phrases are one or two words, so chat holding one ("I'm freezing", "what's up",
"sleep well") is a word or two away from them: a phrase is taken on Moonshine's word alone only up
to as_written_regret, with pocketsphinx agreeing only up to phrase_max_regret, and never on the
alignment or the reranking score alone. A polite form ("please follow me") is taken on Moonshine's
word up to moonshine_alone_regret: pocketsphinx does not know the polite words. Beyond that only up
to polite_written_regret, when Moonshine wrote a polite word ("please", "can", "could"; in noise the
closing "please" is often "clean") and the form is within off_transcript_per_word per word of the
command it wraps, and then when pocketsphinx's grammar heard that command or (where
polite_on_rerank_score) the reranking score reaches min_rerank_score; not in noise, where Moonshine
makes "please" of any "pl..." ("play some music" was taken as "please follow me").
Whatever the path, beyond as_written_regret a form is not taken when Moonshine wrote some of its
words and nothing else ("Left" for "reach left": a word said alone, the rest of the form unheard),
nor when Moonshine finds a longer form of another meaning that holds all its words within
longer_form_ambiguity_regret of it ("reach to the back right" for "reach to the right": in a
reverberant room short words such as "back" are smeared into the next, and the shorter form taken
is often a wrong bearing).
Three rules have the last word. The reranking does not overrule a form Moonshine wrote word for
word ("Please look up." was taken as `lookout`) unless pocketsphinx's grammar heard the other
meaning. A command in `base_moving_commands` needs positive evidence: Moonshine wrote a word of it,
or pocketsphinx's grammar heard it. And a question gives way to a stop phrase that may have been
said (`stop_over_question_regret`): stop outranks everything.

Noise raises every regret, the right form's and chat's alike, so an utterance whose SNR
(front_end.py) is below `noisy_below_snr_db` is judged by `noisy`: limits that keep all chat out of
clean speech turn away commands in noise that looser ones take without taking chat. Across a room
pocketsphinx hears worse still than Moonshine, and its passes agree with Moonshine on forms that
were never said ("are you a robot" verified as "can you move forward" at regret 10): a quiet
utterance whose sounds die away slowly (front_end.fall_time_ms at least `reverberant_from_fall_ms`)
is judged by `reverberant`, the clean limits with a stricter verified path. All sets were tuned on
other espeak voices than the benchmark's (bench/offline_experiments.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from by_your_command.local_speech.rescoring import RerankWeights


@dataclass(frozen=True)
class AcceptLimits:
    """One set of limits (clean, noisy or reverberant speech). Regrets are in nats (moonshine.py)."""

    # --- Taken on Moonshine's word alone: against chat that Moonshine scores near a form.
    # Nearly what Moonshine would write freely: taken with no other evidence (and the only way a
    # phrase is taken on its word); beyond it the "said in part" and "not asked for" checks apply.
    as_written_regret: float = 1.0
    # The reranked best, on Moonshine's word alone (a phrase: as_written_regret).
    moonshine_alone_regret: float = 3.0

    # --- Taken with pocketsphinx's evidence: against chat forced into a form by one model.
    # pocketsphinx's grammar pass heard the same meaning.
    grammar_agrees_regret: float = 9.0
    # The alignment path: pocketsphinx fits the form's words this well (nats per 10 ms frame) and
    # the form leads the next meaning by this much reranking score; against a bad fit or a near tie.
    alignment_path_regret: float = 6.0
    alignment_path_min_per_frame: float = -1.6
    alignment_path_min_margin: float = 1.0
    # A reranking score (rescoring.py) this high is evidence enough on its own.
    min_rerank_score: float = -4.5
    # The verified path (pocketsphinx's grammar and filler model agree), last resort.
    verified_regret: float = 12.0

    # --- Against chat a word away from a short form.
    # A form whose end regret exceeds this is cut short: the model heard more words after it.
    cut_short_regret: float = 0.25
    # Every limit, for the one- or two-word wake/sleep/stop phrases ("what's up", "sleep well").
    phrase_max_regret: float = 6.0
    # When Moonshine wrote words of its own: at most this regret per word of the form ("What's
    # up?" is "look up" at 8.6), beyond moonshine_alone_regret.
    off_transcript_per_word: float = 3.5
    # The same on the verified path, looser: there Moonshine often writes other words for espeak's
    # commands ("Lume my hand" for "move ahead").
    verified_off_transcript_per_word: float = 5.0
    # A longer form of another meaning holding all the form's words, this near, makes it
    # ambiguous: a word more or less ("reach to the (back) right").
    longer_form_ambiguity_regret: float = 5.0

    # --- Polite forms (pocketsphinx does not know the polite words).
    # Beyond moonshine_alone_regret, taken up to this only when Moonshine wrote a polite word and
    # pocketsphinx's grammar heard the command or (if polite_on_rerank_score) the reranking score
    # reaches min_rerank_score; against "play some music" as "please follow me".
    polite_written_regret: float = 9.0
    polite_on_rerank_score: bool = True

    def __post_init__(self) -> None:
        path_limits = (
            self.moonshine_alone_regret,
            self.grammar_agrees_regret,
            self.alignment_path_regret,
            self.verified_regret,
            self.phrase_max_regret,
            self.polite_written_regret,
        )
        values = (
            self.as_written_regret,
            *path_limits,
            self.cut_short_regret,
            self.alignment_path_min_margin,
            self.alignment_path_min_per_frame,
            self.min_rerank_score,
            self.off_transcript_per_word,
            self.verified_off_transcript_per_word,
            self.longer_form_ambiguity_regret,
        )
        if not all(math.isfinite(value) for value in values):
            raise ValueError("the regret limits and margins must be finite")
        if not 0.0 <= self.as_written_regret <= min(path_limits):
            raise ValueError(
                "need 0 <= as_written_regret <= the moonshine_alone, grammar_agrees, alignment_path,"
                " verified, phrase_max and polite_written regrets"
            )
        per_word = (self.off_transcript_per_word, self.verified_off_transcript_per_word)
        if (
            min(
                self.cut_short_regret,
                self.alignment_path_min_margin,
                *per_word,
                self.longer_form_ambiguity_regret,
            )
            < 0
        ):
            raise ValueError(
                "cut_short_regret, alignment_path_min_margin, the off-transcript regrets per word and"
                " longer_form_ambiguity_regret must not be negative"
            )


def _noisy_default() -> AcceptLimits:
    """Looser where Moonshine and pocketsphinx's grammar agree and on the alignment path, stricter
    on Moonshine's word alone (the noise suppression makes it surer of chat too: "move along" as
    "move ahead") and for polite forms. The verified path keeps the clean limit: up to 16 it took 4
    of 2376 tuning chat lines in white and pink noise at 15 dB for 6 more of 892 commands
    (bench/offline_experiments.md)."""
    return AcceptLimits(
        moonshine_alone_regret=2.5,
        grammar_agrees_regret=13.0,
        alignment_path_regret=7.0,
        off_transcript_per_word=5.0,
        polite_on_rerank_score=False,
    )


def _reverberant_default() -> AcceptLimits:
    """The clean limits with the verified path at 9: on tuning voices in quiet rooms (RT60 0.3-0.6
    s) it took 4 of 10 chat utterances acted on away for 5 of 1338 commands
    (bench/offline_experiments.md)."""
    return AcceptLimits(verified_regret=9.0)


@dataclass(frozen=True)
class Acceptance:
    """The limit sets, which one holds for an utterance, and the rules that have the last word."""

    # --- Which set holds.
    clean: AcceptLimits = field(default_factory=AcceptLimits)
    noisy: AcceptLimits = field(default_factory=_noisy_default)
    # Below this SNR (the loud frames over the background, front_end.Cleaned.snr_db) the noisy
    # limits hold.
    noisy_below_snr_db: float = 20.0
    reverberant: AcceptLimits = field(default_factory=_reverberant_default)
    # A quiet utterance whose steepest falls take this long (front_end.fall_time_ms; straight into
    # a microphone mostly 10-80 ms, in a room with RT60 0.5 s 120-220 ms) is judged by `reverberant`.
    reverberant_from_fall_ms: float = 100.0

    # --- Reranking: Moonshine's leading meanings get pocketsphinx's evidence (rescoring.py).
    rescore_meanings: int = 4
    rerank: RerankWeights = field(default_factory=RerankWeights)

    # --- The last word, whatever the path.
    # Commands that drive the base: taken only on positive evidence, Moonshine having written a
    # word of the command or pocketsphinx's grammar having heard it ("bumper" in heavy noise was
    # turned around, Moonshine writing nothing and pocketsphinx hearing "bumper").
    base_moving_commands: tuple[str, ...] = ("move", "turn", "follow")
    # A question gives way to a stop phrase pocketsphinx's grammar heard, or that Moonshine finds
    # within this regret of it (taken if within phrase_max_regret, else neither is): "halt" heard as
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
