"""The default search: Moonshine (its model from the moonshine-cpp wheel) with pocketsphinx as a
second opinion, on held-out voices; and the fallback to pocketsphinx alone without the model."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import pytest

from by_your_command.local_speech.moonshine import MoonshineConfig
from by_your_command.local_speech.recognizer import (
    OfflineRecognizer,
    RecognizerConfig,
    Rejection,
    Search,
)
from by_your_command.local_speech.spoken import RecognitionKind

RATE = 16000
Synthesize = Callable[[str, str], bytes]


@pytest.fixture(scope="module")
def verified() -> OfflineRecognizer:
    return OfflineRecognizer(RecognizerConfig(search=Search.VERIFIED))


@pytest.mark.unit
def test_moonshine_is_the_default_search(recognizer: OfflineRecognizer) -> None:
    assert recognizer.search is Search.MOONSHINE


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "voice", "canonical"),
    [
        ("move back", "en-029", "move@back"),
        ("turn to the right", "en-029", "turn@right"),
        ("follow me", "en-029", "follow@me"),
        ("look up to the left", "en-us+f3", "lookup@left"),
    ],
)
def test_commands_pocketsphinx_alone_misses_are_recognized(
    recognizer: OfflineRecognizer,
    verified: OfflineRecognizer,
    synthesize: Synthesize,
    text: str,
    voice: str,
    canonical: str,
) -> None:
    pcm = synthesize(text, voice)
    assert verified.recognize(pcm, RATE).kind is RecognitionKind.REJECTED  # why Moonshine is there
    result = recognizer.recognize(pcm, RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.COMMAND, canonical), result
    assert 0.0 < result.confidence <= 1.0


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "voice"),
    [
        ("reach for the stars", "en-029"),  # Moonshine's nearest form is "reach"
        ("go to sleep little baby", "en-us+f3"),  # a whole sleep phrase, then more
        ("turn right at the lights", "en-us+m7"),
        ("look at that bird", "en-gb-x-rp"),
    ],
)
def test_chat_that_starts_like_a_command_is_rejected(
    recognizer: OfflineRecognizer, synthesize: Synthesize, text: str, voice: str
) -> None:
    result = recognizer.recognize(synthesize(text, voice), RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.REJECTED, ""), result
    assert result.reason == Rejection.NOT_A_FORM.value


@pytest.mark.unit
def test_without_the_model_it_falls_back_to_pocketsphinx_and_says_so(
    tmp_path: Path, synthesize: Synthesize, caplog: pytest.LogCaptureFixture
) -> None:
    config = RecognizerConfig(moonshine=MoonshineConfig(model_dir=str(tmp_path)))  # empty: no model
    with caplog.at_level(logging.WARNING):
        fallback = OfflineRecognizer(config)
    assert fallback.search is Search.VERIFIED
    assert "without the Moonshine model" in caplog.text
    result = fallback.recognize(synthesize("look up", "en-us+m7"), RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.COMMAND, "lookup")


@pytest.mark.unit
def test_moonshine_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="positive"):
        MoonshineConfig(beam=0)
