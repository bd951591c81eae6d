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


@pytest.mark.unit
def test_pocketsphinx_knows_only_the_words_it_can_hear(recognizer: OfflineRecognizer) -> None:
    """Its dictionary holds the forms' and filler words, not all 126k: the filler model's
    search is then built in milliseconds instead of seconds."""
    decoder = recognizer._decoder
    assert decoder.lookup_word("left") is not None and decoder.lookup_word("the") is not None
    assert all(decoder.lookup_word(word) is not None for word in recognizer.config.filler_words)
    assert decoder.lookup_word("banana") is None


def _form(recognizer: OfflineRecognizer, words: str) -> int:
    return next(i for i, form in enumerate(recognizer.forms) if form.words == words)


@pytest.mark.unit
def test_a_near_form_is_taken_only_if_it_ends_where_the_speech_ends_and_stands_out(
    recognizer: OfflineRecognizer,
) -> None:
    from by_your_command.offline.moonshine import FormScore

    stop, look, lookup = (_form(recognizer, w) for w in ("stop", "look out", "look up"))
    choose = recognizer._moonshine_choice
    assert choose([]) is None
    sure = FormScore(stop, -1.0, 1.5)
    assert choose([sure]) is sure  # nearly what Moonshine wrote
    near = FormScore(stop, -4.0, 3.5, end_regret=0.0)
    assert choose([near, FormScore(look, -9.0, 8.0)]) is near  # misheard a little, ends there
    # "stop by later": the words fit, but the model wanted to go on after "stop".
    assert choose([FormScore(stop, -4.0, 3.5, end_regret=3.0), FormScore(look, -9.0, 8.0)]) is None
    # another meaning nearly as likely: too close to call
    assert choose([FormScore(look, -4.0, 3.5), FormScore(lookup, -5.0, 4.5)]) is None
    assert choose([FormScore(stop, -6.0, 5.0)]) is None  # too far from what was heard


@pytest.mark.unit
def test_moonshine_hears_the_utterance_noise_suppressed(recognizer: OfflineRecognizer) -> None:
    rng = np.random.default_rng(5)
    speech = np.zeros(RATE, dtype=np.float64)
    speech[4000:12000] = np.sin(np.arange(8000) / 5.0) * 8000  # a "word" between pauses
    noisy = np.clip(speech + rng.normal(0.0, 800.0, RATE), -32768, 32767).astype(np.int16)
    audio = recognizer._moonshine_input(noisy)
    assert len(audio) == RATE and audio.dtype == np.float32
    pause = slice(0, 3000)
    assert np.sqrt(np.mean(audio[pause] ** 2)) < 0.5 * np.sqrt(np.mean((noisy[pause] / 32768.0) ** 2))


@pytest.mark.unit
def test_a_form_both_recognizers_heard_is_taken_further_from_the_free_transcript(
    recognizer: OfflineRecognizer,
) -> None:
    from by_your_command.offline.moonshine import FormScore

    index = _form(recognizer, "pan to the left")
    pan_left, pan_right = recognizer.forms[index], recognizer.forms[_form(recognizer, "pan right")]
    other_way = next(f for f in recognizer.forms if f.canonical == "pan@left" and f.words != pan_left.words)
    agrees = recognizer._agrees
    far = FormScore(index, -8.0, 6.0, end_regret=0.0)
    assert recognizer._moonshine_choice([far]) is None  # alone, Moonshine is unsure
    assert agrees(far, pan_left) and agrees(far, other_way)  # same meaning, either wording
    assert not agrees(far, pan_right) and not agrees(far, None)
    assert not agrees(FormScore(index, -8.0, 6.0, end_regret=1.0), pan_left)  # more words followed
    assert not agrees(FormScore(index, -12.0, 9.0), pan_left)  # too far from what was heard
