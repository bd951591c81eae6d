"""Reranking Moonshine's leading meanings with pocketsphinx's evidence (pure functions)."""

from __future__ import annotations

import dataclasses
import math

import pytest

from by_your_command.local_speech.moonshine import FormScore
from by_your_command.local_speech.rescoring import Alignment, Candidate, RerankWeights, leading, rescore

MEANINGS = {0: "lookup@forward", 1: "lookup@forward", 2: "lookup@full-right", 3: "reach@forward", 4: "stop"}


def meaning(score: FormScore) -> str:
    return MEANINGS[score.index]


@pytest.mark.unit
def test_leading_keeps_the_most_likely_form_of_each_of_the_first_meanings() -> None:
    forms = [
        FormScore(0, -2.0, 1.0),
        FormScore(1, -3.0, 2.0),
        FormScore(2, -4.0, 3.0),
        FormScore(3, -5.0, 4.0),
    ]
    assert leading(forms, meaning, 2) == [forms[0], forms[2]]  # form 1 means what form 0 means
    assert leading(forms, meaning, 10) == [forms[0], forms[2], forms[3]]
    assert leading([], meaning, 4) == []


def candidate(
    score: FormScore, alignment: Alignment | None, words: int = 2, grammar_agrees: bool = False
) -> Candidate:
    return Candidate(score, alignment, words, grammar_agrees)


ALIGNMENT_ONLY = RerankWeights(
    logprob=1.0,
    regret=0.0,
    end_regret=0.0,
    alignment=0.04,
    alignment_per_frame=0.0,
    grammar_agrees=0.0,
    words=0.0,
)


@pytest.mark.unit
def test_a_form_that_aligns_much_better_overtakes_a_slightly_likelier_one() -> None:
    forward, full_right = FormScore(0, -4.0, 3.0), FormScore(2, -6.0, 5.0)
    candidates = [candidate(forward, Alignment(-300.0, 150)), candidate(full_right, Alignment(-150.0, 150))]
    ranked = rescore(candidates, ALIGNMENT_ONLY)
    assert [entry.score for entry in ranked] == [full_right, forward]
    assert ranked[0].combined == pytest.approx(-6.0 - 0.04 * 150)
    assert ranked[0].margin == pytest.approx((-6.0 - 0.04 * 150) - (-4.0 - 0.04 * 300))
    assert ranked[1].margin == math.inf
    assert ranked[0].alignment.per_frame == pytest.approx(-1.0)
    assert [entry.score for entry in rescore(candidates, RerankWeights())] == [full_right, forward]
    # without the second opinion Moonshine's order stands
    unweighted = rescore(candidates, dataclasses.replace(ALIGNMENT_ONLY, alignment=0.0))
    assert [entry.score for entry in unweighted] == [forward, full_right]


@pytest.mark.unit
def test_every_piece_of_evidence_counts_with_its_weight() -> None:
    score = FormScore(0, -4.0, 3.0, end_regret=0.5)
    alignment = Alignment(-200.0, 100)
    weights = RerankWeights()
    [plain] = rescore([candidate(score, alignment, words=2)], weights)
    assert plain.combined == pytest.approx(
        0.24 * -4.0 - 0.27 * 3.0 - 0.38 * 0.5 + 0.0062 * -200.0 + 1.0 * -2.0 + 0.68 * 2
    )
    [agreed] = rescore([candidate(score, alignment, words=2, grammar_agrees=True)], weights)
    assert agreed.combined == pytest.approx(plain.combined + weights.grammar_agrees)
    [longer] = rescore([candidate(score, alignment, words=3)], weights)
    assert longer.combined == pytest.approx(plain.combined + weights.words)


@pytest.mark.unit
def test_the_meaning_the_grammar_heard_wins_a_near_tie() -> None:
    first, second = FormScore(0, -4.0, 3.0), FormScore(2, -4.5, 3.5)
    alignment = Alignment(-150.0, 150)
    tie = [candidate(first, alignment), candidate(second, alignment, grammar_agrees=True)]
    assert [entry.score for entry in rescore(tie, RerankWeights())] == [second, first]


@pytest.mark.unit
def test_forms_whose_words_could_not_be_aligned_drop_out() -> None:
    forward, full_right = FormScore(0, -4.0, 3.0), FormScore(2, -6.0, 5.0)
    ranked = rescore(
        [candidate(forward, None), candidate(full_right, Alignment(-400.0, 150))], RerankWeights()
    )
    assert [entry.score for entry in ranked] == [full_right]
    assert rescore([candidate(forward, None, grammar_agrees=True)], RerankWeights()) == []


@pytest.mark.unit
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_weights_must_be_finite(bad: float) -> None:
    for name in ("logprob", "alignment", "words"):
        with pytest.raises(ValueError, match="finite"):
            RerankWeights(**{name: bad})  # type: ignore[arg-type]
