"""Reranking Moonshine's leading meanings with pocketsphinx alignments (pure functions)."""

from __future__ import annotations

import math

import pytest

from by_your_command.offline.moonshine import FormScore
from by_your_command.offline.rescoring import Alignment, leading, rescore

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


@pytest.mark.unit
def test_a_form_that_aligns_much_better_overtakes_a_slightly_likelier_one() -> None:
    forward, full_right = FormScore(0, -4.0, 3.0), FormScore(2, -6.0, 5.0)
    ranked = rescore([forward, full_right], [Alignment(-300.0, 150), Alignment(-150.0, 150)], weight=0.04)
    assert [entry.score for entry in ranked] == [full_right, forward]
    assert ranked[0].combined == pytest.approx(-6.0 - 0.04 * 150)
    assert ranked[0].margin == pytest.approx((-6.0 - 0.04 * 150) - (-4.0 - 0.04 * 300))
    assert ranked[1].margin == math.inf
    assert ranked[0].alignment.per_frame == pytest.approx(-1.0)
    # without the second opinion Moonshine's order stands
    unweighted = rescore([forward, full_right], [Alignment(-300.0, 150), Alignment(-150.0, 150)], weight=0.0)
    assert [entry.score for entry in unweighted] == [forward, full_right]


@pytest.mark.unit
def test_forms_whose_words_could_not_be_aligned_drop_out() -> None:
    forward, full_right = FormScore(0, -4.0, 3.0), FormScore(2, -6.0, 5.0)
    ranked = rescore([forward, full_right], [None, Alignment(-400.0, 150)], weight=0.04)
    assert [entry.score for entry in ranked] == [full_right]
    assert rescore([forward], [None], weight=0.04) == []
