"""Moonshine's leading meanings rescored with a second acoustic model.

Moonshine's best form is often not the right one when it is unsure (espeak's "bumper" written
"Mum put"), but the right one is usually close behind: on the tuning set the right meaning was
Moonshine's first in 85 % of clean and 67 % of noisy commands, among its first four in 97 % and
90 %. pocketsphinx, a different model trained on different data, forced-aligns the words of each
leading meaning to the same audio, and its grammar pass names the meaning it heard. A linear score
of all that evidence (RerankWeights) picks the meaning: first right in 94 % / 89 % of the tuning
set's commands, against 91 % / 85 % for log probability plus a weighted alignment alone. How well
the chosen form aligns per frame, and by how much it beats the next meaning, are evidence for
accepting it (acceptance.py).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Hashable
from dataclasses import dataclass

from by_your_command.local_speech.moonshine import FormScore


@dataclass(frozen=True)
class Alignment:
    """pocketsphinx's forced alignment of a form's words to a whole utterance."""

    log_score: float  # natural log; acoustics relative to the best state of each frame, so <= 0
    frames: int

    @property
    def per_frame(self) -> float:
        return self.log_score / max(self.frames, 1)


@dataclass(frozen=True)
class RerankWeights:
    """What each piece of evidence about a candidate meaning adds to its reranking score: a
    conditional logit fitted on the tuning records (bench/offline_experiments.md;
    bench/tune_offline_reranking.py fits them again)."""

    logprob: float = 0.24  # Moonshine's log probability of the form
    regret: float = -0.27  # how far the form is from what Moonshine would write freely
    end_regret: float = -0.38  # the part of the regret paid for ending there
    alignment: float = 0.0062  # per nat of pocketsphinx's alignment log score
    alignment_per_frame: float = 1.0  # the same per 10 ms frame: a poor fit counts more in short audio
    grammar_agrees: float = 1.3  # pocketsphinx's grammar pass heard this meaning
    # Per word of the spoken form: log probability and regret are sums over tokens, so without it
    # a long form loses to a short one that explains less of the audio.
    words: float = 0.68

    def __post_init__(self) -> None:
        if not all(math.isfinite(value) for value in self.as_tuple()):
            raise ValueError("the reranking weights must be finite")

    def as_tuple(self) -> tuple[float, ...]:
        """In field order, as evidence_vector lists the evidence."""
        return tuple(getattr(self, field.name) for field in dataclasses.fields(self))


@dataclass(frozen=True)
class Candidate:
    """One leading meaning's best form and the evidence about it."""

    score: FormScore  # Moonshine's
    alignment: Alignment | None  # None: pocketsphinx could not fit the words to the audio
    words: int  # in the spoken form
    grammar_agrees: bool  # pocketsphinx's grammar pass heard the same meaning


@dataclass(frozen=True)
class Rescored:
    score: FormScore  # Moonshine's score of the form
    alignment: Alignment
    combined: float  # the reranking score (RerankWeights)
    margin: float  # over the next rescored meaning; inf when there is none


def leading(forms: list[FormScore], meaning: Callable[[FormScore], Hashable], count: int) -> list[FormScore]:
    """The most likely form of each of the `count` most likely meanings, best first (`forms` come
    best first)."""
    chosen: dict[Hashable, FormScore] = {}
    for score in forms:
        if len(chosen) == count:
            break
        chosen.setdefault(meaning(score), score)
    return list(chosen.values())


def evidence_vector(candidate: Candidate, alignment: Alignment) -> tuple[float, ...]:
    """The numbers RerankWeights weighs, one per field and in its field order."""
    score = candidate.score
    return (
        score.logprob,
        score.regret,
        score.end_regret,
        alignment.log_score,
        alignment.per_frame,
        float(candidate.grammar_agrees),
        float(candidate.words),
    )


def rescore(candidates: list[Candidate], weights: RerankWeights) -> list[Rescored]:
    """The candidates that could be aligned, best reranking score first."""
    values = weights.as_tuple()

    def reranking_score(candidate: Candidate, alignment: Alignment) -> float:
        evidence = evidence_vector(candidate, alignment)
        return math.fsum(weight * value for weight, value in zip(values, evidence, strict=True))

    ranked = sorted(
        (
            (reranking_score(candidate, candidate.alignment), candidate.score, candidate.alignment)
            for candidate in candidates
            if candidate.alignment is not None
        ),
        key=lambda entry: -entry[0],
    )
    return [
        Rescored(score, alignment, combined, combined - ranked[i + 1][0] if i + 1 < len(ranked) else math.inf)
        for i, (combined, score, alignment) in enumerate(ranked)
    ]
