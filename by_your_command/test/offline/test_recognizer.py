"""OfflineRecognizer on synthesized speech (voices it was not tuned on), chat and hostile input."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest

from by_your_command.offline.recognizer import OfflineRecognizer, Rejection
from by_your_command.offline.spoken import RecognitionKind

RATE = 16000
Synthesize = Callable[[str, str], bytes]


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "voice", "kind", "canonical"),
    [
        ("look up", "en-us+m7", RecognitionKind.COMMAND, "lookup"),
        ("pan left", "en-us+m7", RecognitionKind.COMMAND, "pan@left"),
        ("go to sleep", "en-us+f3", RecognitionKind.PHRASE, "sleep"),
        ("wake up", "en-gb-x-rp", RecognitionKind.PHRASE, "wake"),
        ("what time is it", "en-us+m7", RecognitionKind.QUESTION, "time"),
    ],
)
def test_spoken_commands_phrases_and_questions_are_recognized(
    recognizer: OfflineRecognizer,
    synthesize: Synthesize,
    text: str,
    voice: str,
    kind: RecognitionKind,
    canonical: str,
) -> None:
    result = recognizer.recognize(synthesize(text, voice), RATE)
    assert (result.kind, result.canonical) == (kind, canonical), result
    assert 0.0 < result.confidence <= 1.0


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "voice"),
    [
        ("I looked up the answer yesterday", "en-us+m7"),
        ("don't stop believing", "en-gb-x-rp"),
        ("what a lovely morning", "en-us+f3"),  # the bare grammar hears lookup@full-right
        ("the meeting starts at nine", "en-029"),  # ... and this as "tell me the time"
        ("are you a robot", "en-us+m7"),  # ... and this as move@left
    ],
)
def test_chat_is_rejected_not_forced_into_a_command(
    recognizer: OfflineRecognizer, synthesize: Synthesize, text: str, voice: str
) -> None:
    result = recognizer.recognize(synthesize(text, voice), RATE)
    assert result.kind is RecognitionKind.REJECTED, result
    assert result.canonical == ""
    assert result.reason in (
        Rejection.NOT_IN_GRAMMAR.value,
        Rejection.UNCONFIRMED.value,
        Rejection.NOT_A_FORM.value,
    )


@pytest.mark.unit
def test_audio_at_another_rate_is_resampled_before_decoding(
    recognizer: OfflineRecognizer, synthesize: Synthesize
) -> None:
    from by_your_command.audio.pcm import resample

    speech = np.frombuffer(synthesize("look up", "en-us+m7"), dtype=np.int16)
    at_44k = resample(speech, RATE, 44100).tobytes()
    assert recognizer.recognize(at_44k, 44100).canonical == "lookup"


def _noise(seconds: float, rms: float) -> bytes:
    samples = np.random.default_rng(7).normal(0.0, rms, int(seconds * RATE))
    return bytes(np.clip(samples, -32768, 32767).astype(np.int16).tobytes())


@pytest.mark.unit
@pytest.mark.parametrize(
    ("pcm", "rate", "reason"),
    [
        (bytes(2 * RATE), RATE, Rejection.SILENCE),  # digital silence
        (_noise(1.0, 20.0), RATE, Rejection.SILENCE),  # a quiet room
        (b"\x01\x02\x03", RATE, Rejection.ODD_BYTES),
        (bytes(2 * RATE), 0, Rejection.BAD_RATE),
        (bytes(2 * RATE), 10**9, Rejection.BAD_RATE),
        (bytes(64), RATE, Rejection.TOO_SHORT),
        (b"", RATE, Rejection.TOO_SHORT),
    ],
)
def test_malformed_or_empty_input_is_rejected_without_decoding(
    recognizer: OfflineRecognizer, pcm: bytes, rate: int, reason: Rejection
) -> None:
    decoded_before = recognizer.stats.decoded
    rejected_before = recognizer.stats.rejections[reason.value]
    result = recognizer.recognize(pcm, rate)
    assert (result.kind, result.reason) == (RecognitionKind.REJECTED, reason.value)
    assert recognizer.stats.rejections[reason.value] == rejected_before + 1
    assert recognizer.stats.decoded == decoded_before


@pytest.mark.unit
def test_an_absurdly_long_utterance_is_refused_unread(recognizer: OfflineRecognizer) -> None:
    hour = bytes(2 * RATE * 3600)
    decoded_before = recognizer.stats.decoded
    result = recognizer.recognize(hour, RATE)
    assert result.reason == Rejection.TOO_LONG.value
    assert recognizer.stats.decoded == decoded_before


@pytest.mark.unit
def test_loud_noise_is_decoded_and_rejected(recognizer: OfflineRecognizer) -> None:
    result = recognizer.recognize(_noise(2.0, 3000.0), RATE)
    assert result.kind is RecognitionKind.REJECTED
    assert recognizer.stats.by_kind[RecognitionKind.REJECTED.value] >= 1


@pytest.mark.unit
def test_a_bare_grammar_forces_chat_into_a_command(synthesize: Synthesize) -> None:
    """Why the garbage model exists: the baseline turns this chat line into a command."""
    from by_your_command.offline.recognizer import RecognizerConfig, Search

    bare = OfflineRecognizer(dataclasses.replace(RecognizerConfig(), search=Search.BARE_GRAMMAR))
    result = bare.recognize(synthesize("what a lovely morning", "en-us+f3"), RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.COMMAND, "lookup@full-right")
