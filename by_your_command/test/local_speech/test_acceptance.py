"""acceptance: the accept limits are checked, and noisy and reverberant utterances are judged by their own."""

from __future__ import annotations

import math

import pytest

from by_your_command.local_speech.acceptance import Acceptance, AcceptLimits


@pytest.mark.unit
def test_limits_are_checked() -> None:
    with pytest.raises(ValueError, match="as_written_regret"):
        AcceptLimits(as_written_regret=5.0, verified_regret=1.0)
    with pytest.raises(ValueError, match="as_written_regret"):
        AcceptLimits(phrase_max_regret=0.5)
    with pytest.raises(ValueError, match="polite"):
        AcceptLimits(polite_written_regret=0.5)
    with pytest.raises(ValueError, match="as_written_regret"):
        AcceptLimits(as_written_regret=-1.0)
    for bad in (
        {"alignment_path_min_per_frame": math.nan},
        {"phrase_max_regret": math.inf},
        {"polite_written_regret": math.nan},
        {"cut_short_regret": math.nan},
        {"min_rerank_score": -math.inf},
    ):
        with pytest.raises(ValueError, match="finite"):
            AcceptLimits(**bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="negative"):
        AcceptLimits(alignment_path_min_margin=-1.0)
    with pytest.raises(ValueError, match="negative"):
        AcceptLimits(off_transcript_per_word=-1.0)
    with pytest.raises(ValueError, match="finite"):
        AcceptLimits(off_transcript_per_word=math.nan)
    with pytest.raises(ValueError, match="negative"):
        AcceptLimits(verified_off_transcript_per_word=-0.5)
    with pytest.raises(ValueError, match="finite"):
        AcceptLimits(verified_off_transcript_per_word=math.inf)
    with pytest.raises(ValueError, match="rescore_meanings"):
        Acceptance(rescore_meanings=0)
    with pytest.raises(ValueError, match="noisy_below_snr_db"):
        Acceptance(noisy_below_snr_db=math.nan)
    for bad_fall in (0.0, -5.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="reverberant_from_fall_ms"):
            Acceptance(reverberant_from_fall_ms=bad_fall)
    for bad_apart in (-1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="stop_over_question_regret"):
            Acceptance(stop_over_question_regret=bad_apart)


@pytest.mark.unit
def test_noisy_and_reverberant_utterances_get_their_own_limits() -> None:
    clean, noisy, reverberant = (
        AcceptLimits(moonshine_alone_regret=3.0),
        AcceptLimits(moonshine_alone_regret=4.0),
        AcceptLimits(moonshine_alone_regret=2.0),
    )
    acceptance = Acceptance(
        clean=clean,
        noisy=noisy,
        reverberant=reverberant,
        noisy_below_snr_db=20.0,
        reverberant_from_fall_ms=100.0,
    )
    assert acceptance.limits(12.0, 0.0) is noisy
    assert acceptance.limits(20.0, 0.0) is clean and acceptance.limits(99.0, 99.0) is clean
    assert acceptance.limits(99.0, 100.0) is reverberant and acceptance.limits(25.0, 180.0) is reverberant
    assert acceptance.limits(12.0, 180.0) is noisy  # under noise the fall time is not seen
    shipped = Acceptance()  # the shipped limits differ
    assert shipped.noisy != shipped.clean
    assert shipped.reverberant.verified_regret < shipped.clean.verified_regret
