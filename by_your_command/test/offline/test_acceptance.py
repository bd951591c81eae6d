"""acceptance: the accept limits are checked, and noisy utterances are judged by their own."""

from __future__ import annotations

import math

import pytest

from by_your_command.offline.acceptance import Acceptance, AcceptLimits


@pytest.mark.unit
def test_limits_are_checked() -> None:
    with pytest.raises(ValueError, match="accept_regret"):
        AcceptLimits(accept_regret=5.0, confirm_regret=1.0)
    with pytest.raises(ValueError, match="accept_regret"):
        AcceptLimits(phrase_regret=0.5)
    with pytest.raises(ValueError, match="accept_regret"):
        AcceptLimits(accept_regret=-1.0)
    for bad in (
        {"aligned_per_frame": math.nan},
        {"phrase_regret": math.inf},
        {"end_regret": math.nan},
        {"evidence_score": -math.inf},
    ):
        with pytest.raises(ValueError, match="finite"):
            AcceptLimits(**bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="negative"):
        AcceptLimits(margin=-1.0)
    with pytest.raises(ValueError, match="negative"):
        AcceptLimits(written_regret_per_word=-1.0)
    with pytest.raises(ValueError, match="finite"):
        AcceptLimits(written_regret_per_word=math.nan)
    with pytest.raises(ValueError, match="rescore_meanings"):
        Acceptance(rescore_meanings=0)
    with pytest.raises(ValueError, match="noisy_below_snr_db"):
        Acceptance(noisy_below_snr_db=math.nan)


@pytest.mark.unit
def test_noisy_utterances_get_the_noisy_limits() -> None:
    clean, noisy = AcceptLimits(near_regret=3.0), AcceptLimits(near_regret=4.0)
    acceptance = Acceptance(clean=clean, noisy=noisy, noisy_below_snr_db=20.0)
    assert acceptance.limits(12.0) is noisy
    assert acceptance.limits(20.0) is clean and acceptance.limits(99.0) is clean
    assert Acceptance().noisy != Acceptance().clean  # the shipped limits differ
