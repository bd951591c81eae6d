"""OfflineRecognizer on synthesized speech (voices it was not tuned on), chat and hostile input."""

from __future__ import annotations

import dataclasses
import functools
import importlib.util
import wave
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pytest

from by_your_command.local_speech.acceptance import AcceptLimits
from by_your_command.local_speech.moonshine import FormScore
from by_your_command.local_speech.recognizer import Evidence, OfflineRecognizer, Rejection
from by_your_command.local_speech.rescoring import Alignment, Candidate, Rescored, rescore
from by_your_command.local_speech.spoken import RecognitionKind, SpokenForm

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
        ("please look up", "en-us+f3", RecognitionKind.COMMAND, "lookup"),
        ("can you pan to the left please", "en-gb-x-rp", RecognitionKind.COMMAND, "pan@left"),
        ("move backward", "en-us+m7", RecognitionKind.COMMAND, "move@back"),
        ("turn around", "en-gb-x-rp", RecognitionKind.COMMAND, "turn@back"),
        ("please stop", "en-us+f3", RecognitionKind.PHRASE, "stop"),
        ("stop it", "en-029", RecognitionKind.PHRASE, "stop"),
        ("stop right there", "en-us+m7", RecognitionKind.PHRASE, "stop"),
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
    [("stop, stop!", "en-us+m7"), ("stop stop stop", "en-gb-x-rp"), ("freeze freeze", "en-us+f3")],
)
def test_a_phrase_said_again_is_that_phrase(
    recognizer: OfflineRecognizer, synthesize: Synthesize, text: str, voice: str
) -> None:
    """Someone who wants the robot to stop says it again; Moonshine writes "Stop, stop", and a
    form that ended after the first "stop" paid for the rest (end regret) and was turned away."""
    result = recognizer.recognize(synthesize(text, voice), RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.PHRASE, "stop"), result


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "voice"),
    [
        ("I looked up the answer yesterday", "en-us+m7"),
        ("don't stop believing", "en-gb-x-rp"),
        ("what a lovely morning", "en-us+f3"),  # the bare grammar hears lookup@full-right
        ("the meeting starts at nine", "en-029"),  # ... and this as "tell me the time"
        ("are you a robot", "en-us+m7"),  # ... and this as move@left
        ("can you look up a recipe", "en-us+f3"),  # a polite command that goes on
        ("open the door please", "en-gb-x-rp"),
        ("what's up", "en-us+f3"),  # Moonshine: "What's up?"; pocketsphinx's grammar: "look up"
        # The form's words in a sentence that does not ask for it (asking.py).
        ("I followed the ball", "en-gb-x-rp"),
        ("I reached forward", "en-029"),
        ("they moved left", "en-gb-x-rp"),
        ("I'm moving forward", "en-us+f3"),
        ("I looked up", "en-us+m7"),
        ("if you turn left", "en-us+m7"),  # verified as "could you turn left" before
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


def _recorded_voice() -> tuple[npt.NDArray[np.int16], int]:
    """The one recording of a human voice on this machine: Beckett, read aloud, shipped with
    moonshine-cpp for its own tests."""
    spec = importlib.util.find_spec("moonshine_cpp")
    assert spec is not None and spec.submodule_search_locations, "moonshine-cpp is a dependency"
    path = Path(next(iter(spec.submodule_search_locations))) / "test-data" / "beckett.wav"
    with wave.open(str(path)) as file:
        assert file.getnchannels() == 1 and file.getsampwidth() == 2
        samples = np.frombuffer(file.readframes(file.getnframes()), dtype="<i2").astype(np.int16)
        return samples, file.getframerate()


# The recording's lines (seconds), each with 0.3 s either side, and their words.
RECORDED_LINES = [
    (0.03, 3.0, "ever tried ever failed"),
    (3.24, 5.82, "no matter try again"),
    (6.36, 7.71, "fail again"),
    (7.71, 9.96, "fail better"),
]


@pytest.mark.unit
@pytest.mark.parametrize(("start_s", "end_s", "words"), RECORDED_LINES)
def test_a_recorded_human_voice_is_heard_word_for_word_and_its_chat_is_not_a_command(
    recognizer: OfflineRecognizer, start_s: float, end_s: float, words: str
) -> None:
    """Short lines that sound like orders ("try again", "fail better") in a real voice: Moonshine
    writes them, and no form is near enough to be taken."""
    samples, rate = _recorded_voice()
    utterance = samples[int(start_s * rate) : int(end_s * rate)]
    heard = recognizer.evidence(utterance).free_text
    assert " ".join("".join(c for c in heard.lower() if c.isalpha() or c == " ").split()) == words
    result = recognizer.recognize(utterance.tobytes(), rate)
    assert result.kind is RecognitionKind.REJECTED, result


@pytest.mark.unit
@pytest.mark.parametrize("where", ["white noise at 10 dB", "a room"])
def test_a_recorded_human_voice_in_noise_or_across_a_room_is_still_no_command(
    recognizer: OfflineRecognizer, in_room: Callable[[np.ndarray, float], np.ndarray], where: str
) -> None:
    """The same lines, where both models hear worse and limits are looser (noise) or a room's
    reflections smear the words."""
    samples, rate = _recorded_voice()
    rng = np.random.default_rng(11)
    for start_s, end_s, _ in RECORDED_LINES:
        line = samples[int(start_s * rate) : int(end_s * rate)].astype(np.float64)
        if where == "a room":
            heard = in_room(line, 0.5)
        else:  # noise a tenth of the line's power, also a quarter second either side (VAD pre-roll)
            heard = rng.normal(0.0, np.sqrt(np.mean(line**2) / 10.0), len(line) + rate // 2)
            heard[rate // 4 : rate // 4 + len(line)] += line
        utterance = np.clip(heard, -32768, 32767).astype("<i2")
        result = recognizer.recognize(utterance.tobytes(), rate)
        assert result.kind is RecognitionKind.REJECTED, (where, start_s, result)


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
    from by_your_command.local_speech.recognizer import RecognizerConfig, Search

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


@pytest.mark.unit
def test_polite_forms_are_moonshines_alone(recognizer: OfflineRecognizer, synthesize: Synthesize) -> None:
    """pocketsphinx's grammar pass is built from the plain forms (with polite words it searched
    three times slower and heard "can you" in the noise before "turn left"); Moonshine scores the
    polite forms, and pocketsphinx still aligns them."""
    pcm = synthesize("could you turn left please", "en-us+m7")
    evidence = recognizer.evidence(np.frombuffer(pcm, "<i2"))
    best = recognizer.forms[evidence.forms[0].index]
    assert best.words == "could you turn left please" and best.polite
    assert not {"could", "please"} & set(evidence.grammar_text.split())
    (candidate,) = [c for c in evidence.candidates if c.score.index == evidence.forms[0].index]
    assert candidate.alignment is not None
    result = recognizer.recognize(pcm, RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.COMMAND, "turn@left")


def _form(recognizer: OfflineRecognizer, words: str) -> int:
    return next(i for i, form in enumerate(recognizer.forms) if form.words == words)


def _rescored(
    score: FormScore, per_frame: float = -1.0, margin: float = 5.0, combined: float = -20.0
) -> Rescored:
    return Rescored(score, Alignment(100 * per_frame, 100), combined, margin)


def _chooser(
    recognizer: OfflineRecognizer, limits: AcceptLimits | None = None
) -> Callable[..., FormScore | None]:
    """The reranked choice under `limits` (the clean ones by default), Moonshine having written
    nothing unless a test says what it wrote (`free_text=`)."""
    limits = limits or recognizer.config.acceptance.clean
    return functools.partial(recognizer._rescored_choice, limits=limits, free_text="")


@pytest.mark.unit
def test_the_reranked_form_is_taken_only_if_it_ends_where_the_speech_ends_and_the_evidence_holds(
    recognizer: OfflineRecognizer,
) -> None:
    look_up = _form(recognizer, "look up")
    choose = _chooser(recognizer)
    assert choose([], None) is None
    near = FormScore(look_up, -4.0, 2.5, end_regret=0.0)
    assert choose([_rescored(near)], None) is near  # misheard a little, ends there
    # "look up the answer": the words fit, but the model wanted to go on after "look up".
    assert choose([_rescored(FormScore(look_up, -4.0, 2.5, end_regret=3.0))], None) is None
    # further from what Moonshine wrote: taken if it aligns well and stands out ...
    far = FormScore(look_up, -7.0, 5.5)
    assert choose([_rescored(far, per_frame=-1.2, margin=3.0)], None) is far
    assert choose([_rescored(far, per_frame=-2.5, margin=3.0)], None) is None  # aligns badly
    assert choose([_rescored(far, per_frame=-1.2, margin=0.5)], None) is None  # a near tie
    assert choose([_rescored(FormScore(look_up, -9.0, 7.5), per_frame=-1.0)], None) is None  # too far


@pytest.mark.unit
def test_a_form_the_grammar_heard_too_is_taken_further_from_the_free_transcript(
    recognizer: OfflineRecognizer,
) -> None:
    index = _form(recognizer, "pan to the left")
    pan_left, pan_right = recognizer.forms[index], recognizer.forms[_form(recognizer, "pan right")]
    other_way = next(f for f in recognizer.forms if f.canonical == "pan@left" and f.words != pan_left.words)
    choose = _chooser(recognizer)
    far = _rescored(FormScore(index, -10.0, 8.0, end_regret=0.0), per_frame=-3.0)
    assert choose([far], None) is None  # alone, the evidence is too weak
    assert choose([far], pan_left) is far.score and choose([far], other_way) is far.score  # either wording
    assert choose([far], pan_right) is None
    more_words = _rescored(FormScore(index, -10.0, 8.0, end_regret=1.0), per_frame=-3.0)
    assert choose([more_words], pan_left) is None
    assert choose([_rescored(FormScore(index, -12.0, 10.0), per_frame=-3.0)], pan_left) is None  # too far


@pytest.mark.unit
def test_a_short_form_must_be_near_the_words_moonshine_wrote(recognizer: OfflineRecognizer) -> None:
    """Beyond Moonshine's word alone, the regret per word of the form is limited when Moonshine
    wrote words of its own: "What's up?" is a word away from "look up"."""
    look_up, pan_left = _form(recognizer, "look up"), _form(recognizer, "pan to the left")
    clean, noisy = recognizer.config.acceptance.clean, recognizer.config.acceptance.noisy
    choose = _chooser(recognizer, clean)
    heard = recognizer.forms[look_up]
    regret = 2 * clean.off_transcript_per_word + 0.5  # within grammar_agrees_regret
    assert regret <= clean.grammar_agrees_regret
    far = _rescored(FormScore(look_up, -10.0, regret))
    assert choose([far], heard) is far.score  # Moonshine wrote nothing: no evidence against it
    assert choose([far], heard, free_text="...") is far.score
    assert choose([far], heard, free_text="What's up?") is None
    assert _chooser(recognizer, noisy)([far], heard, free_text="What's up?") is far.score  # noise
    near = _rescored(FormScore(look_up, -3.0, clean.moonshine_alone_regret))
    assert choose([near], None, free_text="Book up.") is near.score  # Moonshine's word alone
    longer = _rescored(FormScore(pan_left, -10.0, regret))  # four words
    assert choose([longer], recognizer.forms[pan_left], free_text="Then to the left.") is longer.score


@pytest.mark.unit
def test_a_reranking_score_that_weighs_enough_evidence_is_taken_on_its_own(
    recognizer: OfflineRecognizer,
) -> None:
    """Beyond every regret limit, aligning poorly per frame and nearly tied: the reranking score
    (all the evidence weighed) decides, never for a phrase and never past the end."""
    look_up, freeze = _form(recognizer, "look up"), _form(recognizer, "freeze")
    limits = recognizer.config.acceptance.clean
    choose = _chooser(recognizer, limits)
    far = FormScore(look_up, -12.0, 10.0)
    strong, weak = limits.min_rerank_score + 0.5, limits.min_rerank_score - 0.5
    assert choose([_rescored(far, per_frame=-2.5, margin=0.1, combined=strong)], None) is far
    assert choose([_rescored(far, per_frame=-2.5, margin=0.1, combined=weak)], None) is None
    assert choose([_rescored(FormScore(freeze, -12.0, 10.0), -2.5, 0.1, combined=strong)], None) is None
    ends_early = FormScore(look_up, -12.0, 10.0, end_regret=2.0)
    assert choose([_rescored(ends_early, per_frame=-2.5, margin=0.1, combined=strong)], None) is None


@pytest.mark.unit
def test_a_polite_form_needs_moonshines_word_or_its_politeness_and_more_evidence(
    recognizer: OfflineRecognizer,
) -> None:
    """pocketsphinx does not know the polite words, and in noise Moonshine makes "please" of any
    "pl..." ("play some music" as "please follow me"): beyond moonshine_alone_regret a polite form is taken
    only when Moonshine wrote a polite word, within the written limit per word of the command (not
    of the polite words it wrote too), and pocketsphinx's grammar heard the command it wraps or,
    in quiet only, the reranking score is evidence enough. Never on the alignment path."""
    plain, polite = _form(recognizer, "follow me"), _form(recognizer, "please follow me")
    limits = recognizer.config.acceptance.noisy
    choose = _chooser(recognizer, limits)
    near = limits.moonshine_alone_regret - 0.5
    assert choose([_rescored(FormScore(polite, -3.0, near))], None) is not None
    strong = {"per_frame": -1.0, "margin": 5.0, "combined": limits.min_rerank_score + 3.0}
    heard = recognizer.forms[plain]
    for regret in (limits.alignment_path_regret - 0.5, limits.polite_written_regret - 0.5):
        assert choose([_rescored(FormScore(plain, -9.0, regret), **strong)], heard) is not None
        assert choose([_rescored(FormScore(polite, -9.0, regret), **strong)], heard) is None  # wrote nothing
    within = FormScore(polite, -9.0, limits.polite_written_regret - 0.5)
    assert choose([_rescored(within)], heard, free_text="Please follow the meat.") is within
    assert choose([_rescored(within)], heard, free_text="Lay some music.") is None  # no polite word
    assert choose([_rescored(within)], None, free_text="Please follow the meat.") is None  # grammar did not
    beyond = FormScore(polite, -9.0, limits.polite_written_regret + 0.5)
    assert choose([_rescored(beyond)], heard, free_text="Please follow the meat.") is None
    # "follow me" is two words: taken up to off_transcript_per_word x 2 from what Moonshine wrote.
    clean = recognizer.config.acceptance.clean
    choose_clean = _chooser(recognizer, clean)
    near_written = FormScore(polite, -9.0, 2 * clean.off_transcript_per_word - 0.5)
    far = FormScore(polite, -9.0, 2 * clean.off_transcript_per_word + 0.5)
    assert clean.moonshine_alone_regret < near_written.regret and far.regret <= clean.polite_written_regret
    assert choose_clean([_rescored(near_written)], heard, free_text="Please follow the meat.") is near_written
    assert choose_clean([_rescored(far)], heard, free_text="Please follow the meat.") is None
    # The grammar heard something else: the reranking score decides, in quiet only.
    for evidence, taken in ((clean.min_rerank_score + 0.5, True), (clean.min_rerank_score - 0.5, False)):
        chosen = choose_clean([_rescored(near_written, combined=evidence)], None, free_text="Please follow.")
        assert (chosen is near_written) is taken, evidence
    sure = _rescored(within, combined=limits.min_rerank_score + 3.0)
    assert choose([sure], None, free_text="Please follow the meat.") is None  # in noise


@pytest.mark.unit
def test_a_polite_command_in_noise_is_taken_when_pocketsphinx_heard_the_command(
    recognizer: OfflineRecognizer, synthesize: Synthesize
) -> None:
    """In noise Moonshine is rarely sure of a polite form word for word: here it wrote "Can you
    look out to the light?" and put "can you look out to the right" at regret 5.6, beyond the noisy
    moonshine_alone_regret; pocketsphinx's grammar heard "lookout to the right"."""
    speech = synthesize("can you look out to the right", "en-us+m7")
    line = np.frombuffer(speech, dtype=np.int16).astype(np.float64)
    # White noise at 15 dB below the speech, also a quarter second either side (VAD pre-roll).
    heard = np.random.default_rng(15).normal(0.0, np.sqrt(np.mean(line**2) / 10**1.5), len(line) + RATE // 2)
    heard[RATE // 4 : RATE // 4 + len(line)] += line
    result = recognizer.recognize(np.clip(heard, -32768, 32767).astype("<i2").tobytes(), RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.COMMAND, "lookout@right"), result


@pytest.mark.unit
def test_a_polite_command_the_grammar_misheard_is_taken_on_the_reranking_score(
    recognizer: OfflineRecognizer, synthesize: Synthesize
) -> None:
    """pocketsphinx's grammar knows no polite words and forces them into some form ("look up full
    left"); Moonshine wrote "Can you move forward left?". The reranking of Moonshine's leading
    meanings with pocketsphinx's alignments puts "could you move full left" first."""
    result = recognizer.recognize(synthesize("could you move full left", "en-us+f3"), RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.COMMAND, "move@full-left"), result


@pytest.mark.unit
def test_an_extra_form_is_taken_on_moonshines_word_alone(recognizer: OfflineRecognizer) -> None:
    """People saying "down" or "nine" alone (Speech Commands): Moonshine put "turn around" first at
    regret 7.5-10.7, and pocketsphinx's passes, had they known the form, heard it too. The extra
    forms are not in pocketsphinx's grammar, and no other path takes them."""
    turn_around = _form(recognizer, "turn around")
    assert recognizer.forms[turn_around].extra and "turn around" not in recognizer._pocketsphinx_forms
    acceptance = recognizer.config.acceptance
    limits = acceptance.noisy
    choose = _chooser(recognizer, limits)
    strong = {"per_frame": -1.0, "margin": 5.0, "combined": limits.min_rerank_score + 3.0}
    assert choose([_rescored(FormScore(turn_around, -10.0, 9.15), **strong)], None) is None
    assert (
        choose([_rescored(FormScore(turn_around, -3.0, limits.moonshine_alone_regret - 0.5))], None)
        is not None
    )
    heard = Evidence(
        acceptance.noisy_below_snr_db - 5.0, [FormScore(turn_around, -10.0, 9.15)], "", "turn around", []
    )
    assert recognizer.decide(heard, acceptance, lambda: "turn around") is None  # not verified either


@pytest.mark.unit
def test_a_phrase_needs_stronger_evidence_than_a_command(recognizer: OfflineRecognizer) -> None:
    """Chat holding a phrase word ("I'm freezing", "what's up") is a word away from the phrase."""
    freeze, look_up = _form(recognizer, "freeze"), _form(recognizer, "look up")
    choose = _chooser(recognizer)
    aligned = (-1.2, 3.0)  # aligns well, stands out
    assert choose([_rescored(FormScore(look_up, -7.0, 5.5), *aligned)], None) is not None
    assert choose([_rescored(FormScore(freeze, -7.0, 5.5), *aligned)], None) is None  # not on alignment alone
    # On Moonshine's word alone, only nearly what it wrote ("what's up" is "wake up" at 1.1 in noise).
    assert choose([_rescored(FormScore(look_up, -3.0, 1.5), -3.0)], None) is not None
    assert choose([_rescored(FormScore(freeze, -3.0, 1.5), -3.0)], None) is None
    assert choose([_rescored(FormScore(freeze, -2.0, 0.5), -3.0)], None) is not None
    heard_freeze = recognizer.forms[freeze]
    assert choose([_rescored(FormScore(freeze, -7.0, 5.5), -3.0)], heard_freeze) is not None
    assert (
        choose([_rescored(FormScore(freeze, -9.0, 7.5), -3.0)], heard_freeze) is None
    )  # beyond phrase_max_regret
    assert choose([_rescored(FormScore(look_up, -9.0, 7.5), -3.0)], recognizer.forms[look_up]) is not None


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "voice", "canonical"),
    [
        ("look up full right", "en-gb", "lookup@full-right"),
        ("move full left", "en-us", "move@full-left"),
        ("move full right", "en-us", "move@full-right"),  # Moonshine: "Move forward", and sure of it
    ],
)
def test_pocketsphinx_alignments_rerank_what_moonshine_misheard(
    recognizer: OfflineRecognizer, synthesize: Synthesize, text: str, voice: str, canonical: str
) -> None:
    pcm = synthesize(text, voice)
    samples = np.frombuffer(pcm, dtype="<i2").astype(np.int16)
    forms = recognizer._scorer.analyse(recognizer._moonshine_input(samples).audio).forms  # type: ignore[union-attr]
    meaning_of = recognizer._meaning
    assert meaning_of(forms[0])[1] != canonical  # Moonshine alone: "forward" for "full right/left"
    # the alignments alone (the grammar pass heard nothing) put the right meaning first
    candidates = recognizer._candidates(recognizer._prepared(samples), forms, None)
    reranked = rescore(candidates, recognizer.config.acceptance.rerank)
    assert meaning_of(reranked[0].score)[1] == canonical
    result = recognizer.recognize(pcm, RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.COMMAND, canonical), result


@pytest.mark.unit
def test_moonshine_hears_the_utterance_noise_suppressed(recognizer: OfflineRecognizer) -> None:
    rng = np.random.default_rng(5)
    speech = np.zeros(RATE, dtype=np.float64)
    speech[4000:12000] = np.sin(np.arange(8000) / 5.0) * 8000  # a "word" between pauses
    noisy = np.clip(speech + rng.normal(0.0, 800.0, RATE), -32768, 32767).astype(np.int16)
    audio = recognizer._moonshine_input(noisy).audio
    assert len(audio) == RATE and audio.dtype == np.float32
    pause = slice(0, 3000)
    assert np.sqrt(np.mean(audio[pause] ** 2)) < 0.5 * np.sqrt(np.mean((noisy[pause] / 32768.0) ** 2))


@pytest.mark.unit
def test_the_verified_form_is_taken_only_if_it_ends_where_the_speech_ends(
    recognizer: OfflineRecognizer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ "he reached the top": pocketsphinx's grammar and filler model both heard "sleep", and
    Moonshine's "sleep" ends early (the model heard more words)."""
    from by_your_command.local_speech.moonshine import Analysis, Transcript

    sleep = _form(recognizer, "sleep")
    scorer = recognizer._scorer
    assert scorer is not None
    heard = {"grammar": "sleep time", "filler": "sleep"}
    monkeypatch.setattr(recognizer, "_decode", lambda audio, search: (heard[search], 0.5))
    monkeypatch.setattr(recognizer, "_align", lambda audio, words: None)  # no reranking
    speech = (np.sin(np.arange(RATE) / 3.0) * 3000).astype("<i2").tobytes()

    def decided(end_regret: float) -> RecognitionKind:
        analysis = Analysis(
            # Without its subject: "He" alone now turns it away (asking.py).
            [FormScore(sleep, -6.0, 5.0, end_regret)],
            Transcript("Reached the top.", -3.0, True),
        )
        monkeypatch.setattr(scorer, "analyse", lambda audio: analysis)
        return recognizer.recognize(speech, RATE).kind

    assert decided(end_regret=2.9) is RecognitionKind.REJECTED
    assert decided(end_regret=0.0) is RecognitionKind.PHRASE


@pytest.mark.unit
def test_a_form_moonshine_is_sure_of_gives_way_to_a_meaning_that_aligns_much_better(
    recognizer: OfflineRecognizer, synthesize: Synthesize
) -> None:
    pcm = synthesize("move full right", "en-us")
    samples = np.frombuffer(pcm, dtype="<i2").astype(np.int16)
    best = recognizer._scorer.analyse(recognizer._moonshine_input(samples).audio).forms[0]  # type: ignore[union-attr]
    assert (
        recognizer._meaning(best)[1] == "move@forward"
        and best.regret <= recognizer.config.acceptance.clean.as_written_regret
    )
    assert recognizer.recognize(pcm, RATE).canonical == "move@full-right"


@pytest.mark.unit
def test_a_noisy_utterance_is_judged_by_the_noisy_limits(
    recognizer: OfflineRecognizer, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Noise raises every regret: a form at regret 4 is too far from clean speech, not from speech
    under noise (acceptance.py)."""
    from by_your_command.local_speech.acceptance import Acceptance, AcceptLimits
    from by_your_command.local_speech.moonshine import Analysis, Transcript

    acceptance = Acceptance(
        clean=AcceptLimits(moonshine_alone_regret=3.0), noisy=AcceptLimits(moonshine_alone_regret=4.5)
    )
    monkeypatch.setattr(recognizer, "config", dataclasses.replace(recognizer.config, acceptance=acceptance))
    monkeypatch.setattr(recognizer, "_decode", lambda audio, search: ("", 0.0))  # pocketsphinx heard nothing
    monkeypatch.setattr(recognizer, "_align", lambda audio, words: Alignment(-300.0, 100))  # aligns poorly
    look_up = _form(recognizer, "look up")
    analysis = Analysis([FormScore(look_up, -5.0, 4.0, 0.0)], Transcript("Look at.", -3.0, True))
    assert recognizer._scorer is not None
    monkeypatch.setattr(recognizer._scorer, "analyse", lambda audio: analysis)
    rng = np.random.default_rng(3)
    word = np.zeros(RATE)
    word[4000:12000] = np.sin(np.arange(8000) / 5.0) * 8000
    quiet_pauses = word.astype("<i2")
    noisy = np.clip(word + rng.normal(0.0, 1500.0, RATE), -32768, 32767).astype("<i2")
    assert recognizer._moonshine_input(noisy).snr_db < acceptance.noisy_below_snr_db
    assert recognizer._moonshine_input(quiet_pauses).snr_db >= acceptance.noisy_below_snr_db
    assert recognizer.recognize(noisy.tobytes(), RATE).canonical == "lookup"
    assert recognizer.recognize(quiet_pauses.tobytes(), RATE).kind is RecognitionKind.REJECTED


@pytest.mark.unit
def test_recorded_evidence_is_decided_without_decoding_and_the_filler_pass_is_asked_last(
    recognizer: OfflineRecognizer,
) -> None:
    """decide() is what recognize() runs on its evidence; the tuning script replays records with it."""
    look_up = _form(recognizer, "look up")
    acceptance = recognizer.config.acceptance
    asked: list[str] = []

    def filler(heard: str) -> Callable[[], str]:
        def ask() -> str:
            asked.append(heard)
            return heard

        return ask

    sure = Evidence(40.0, [FormScore(look_up, -1.0, 0.2)], "Look up.", "", [])
    assert recognizer.decide(sure, acceptance, filler("look up")) == sure.forms[0]
    assert asked == []  # Moonshine's word was enough
    unsure = Evidence(40.0, [FormScore(look_up, -8.0, 7.0)], "Look at.", "look up", [])
    assert recognizer.decide(unsure, acceptance, filler("look up")) == unsure.forms[0]  # verified
    assert recognizer.decide(unsure, acceptance, filler("look at the")) is None  # the filler model disagrees
    assert asked == ["look up", "look at the"]
    assert recognizer.decide(Evidence(40.0, [], "", "", []), acceptance, filler("look up")) is None
    assert len(asked) == 2


@pytest.mark.unit
def test_noise_does_not_loosen_the_verified_path(recognizer: OfflineRecognizer) -> None:
    """ "track my order" in pink noise: Moonshine wrote it word for word, both pocketsphinx passes
    heard "track the ball", which Moonshine put at regret 14.2. Under noise every regret grows, but
    a looser verified path took 4 tuning chat lines for 6 commands (bench/offline_experiments.md)."""
    track_the_ball = _form(recognizer, "track the ball")
    acceptance = recognizer.config.acceptance
    noisy_snr = acceptance.noisy_below_snr_db - 3.0

    def verified(regret: float) -> FormScore | None:
        forms = [FormScore(track_the_ball, -16.0, regret)]
        evidence = Evidence(noisy_snr, forms, "Track my order.", "track the ball", [])
        return recognizer.decide(evidence, acceptance, lambda: "track the ball")

    assert verified(14.2) is None
    assert verified(11.0) is not None  # a command both pocketsphinx passes heard, Moonshine near it


@pytest.mark.unit
def test_the_verified_form_must_be_near_the_words_moonshine_wrote(recognizer: OfflineRecognizer) -> None:
    """A person saying "up" (Speech Commands): Moonshine wrote "Up." and put "bumper" at regret
    9.1, and both pocketsphinx passes, which know only the forms' words, heard "bumper"."""
    bumper = _form(recognizer, "bumper")
    acceptance = recognizer.config.acceptance

    def verified(free_text: str, regret: float) -> FormScore | None:
        evidence = Evidence(40.0, [FormScore(bumper, -12.0, regret)], free_text, "bumper", [])
        return recognizer.decide(evidence, acceptance, lambda: "bumper")

    assert verified("Up.", 9.1) is None
    assert verified("", 9.1) is not None  # Moonshine wrote nothing: no evidence against it
    assert verified("Mum put.", acceptance.clean.verified_off_transcript_per_word - 0.5) is not None
    # A polite form's limit counts the command's words: its polite words earn no allowance
    # ("don't look up" in noise, written "No need to look up", was verified as "please look out").
    please_look_out = _form(recognizer, "please look out")
    per_word = acceptance.clean.verified_off_transcript_per_word
    for regret, taken in ((2 * per_word - 0.5, True), (2 * per_word + 0.5, False)):
        assert regret <= acceptance.clean.verified_regret
        forms = [FormScore(please_look_out, -12.0, regret)]
        evidence = Evidence(40.0, forms, "Please look at that.", "look out", [])
        assert (recognizer.decide(evidence, acceptance, lambda: "look out") is not None) is taken, regret


@pytest.mark.unit
def test_a_word_said_alone_is_not_a_form_that_holds_it(recognizer: OfflineRecognizer) -> None:
    """People saying "left" or "up" alone: Moonshine wrote "Left" and "Up.", and pocketsphinx's
    passes heard the forms holding the word. Beyond Moonshine's own word, a form of which Moonshine
    wrote only some words (and nothing else) was not said."""
    reach_left, look_up = _form(recognizer, "reach left"), _form(recognizer, "look up")
    acceptance = recognizer.config.acceptance

    def decided(index: int, free_text: str, regret: float) -> FormScore | None:
        heard = recognizer.forms[index].words
        evidence = Evidence(40.0, [FormScore(index, -8.0, regret)], free_text, heard, [])
        return recognizer.decide(evidence, acceptance, lambda: heard)

    agreeing = 2 * acceptance.clean.off_transcript_per_word - 0.5  # the grammar agrees, near enough
    assert decided(look_up, "Up.", agreeing) is None
    assert decided(look_up, "Look. Up!", agreeing) is not None  # all of its words
    assert decided(look_up, "Look at.", agreeing) is not None  # other words: near enough to them
    assert decided(reach_left, "Left, left.", 8.0) is None  # verified, within 5 per word
    assert decided(reach_left, "", 8.0) is not None
    assert decided(look_up, "Up.", acceptance.clean.as_written_regret) is not None  # Moonshine's own word


@pytest.mark.unit
def test_a_form_is_not_taken_when_moonshine_wrote_it_told_of_forbidden_or_as_a_condition(
    recognizer: OfflineRecognizer,
) -> None:
    """ "I followed the ball": Moonshine wrote it word for word, found "follow the ball" at regret
    5-7, and pocketsphinx's grammar heard the form; every voice's was taken before."""
    follow_ball = _form(recognizer, "follow the ball")
    acceptance = recognizer.config.acceptance

    def decided(free_text: str, regret: float) -> FormScore | None:
        heard = recognizer.forms[follow_ball].words
        evidence = Evidence(40.0, [FormScore(follow_ball, -8.0, regret)], free_text, heard, [])
        return recognizer.decide(evidence, acceptance, lambda: heard)

    assert decided("I followed the ball.", 6.0) is None
    assert decided("She follows the ball.", 6.0) is None
    assert decided("Don't follow the ball.", 6.0) is None
    assert decided("If you follow the ball,", 6.0) is None
    assert decided("Follow the bowl.", 6.0) is not None  # misheard, but told of nothing
    assert decided("", 6.0) is not None
    assert decided("I followed the ball.", acceptance.clean.as_written_regret) is not None  # its own words


@pytest.mark.unit
def test_a_form_is_not_taken_when_moonshine_finds_it_with_a_word_more_nearly_as_likely(
    recognizer: OfflineRecognizer,
) -> None:
    """ "reach to the back right" in a reverberant room: Moonshine wrote "Reach to the band ride."
    and found the form said at regret 6.1, both pocketsphinx passes heard "reach to the right"
    (regret 8.6). One short word apart, a wrong bearing either way: neither is taken."""
    shorter, longer = _form(recognizer, "reach to the right"), _form(recognizer, "reach to the back right")
    acceptance = recognizer.config.acceptance

    def decided(longer_regret: float, longer_form: int = longer) -> FormScore | None:
        forms = [FormScore(longer_form, -9.8, longer_regret), FormScore(shorter, -11.0, 8.6)]
        evidence = Evidence(99.0, forms, "Reach to the band ride.", "reach to the right", [])
        return recognizer.decide(evidence, acceptance, lambda: "reach to the right")

    assert decided(6.1) is None
    assert decided(8.6 + acceptance.clean.longer_form_ambiguity_regret + 0.1) is not None  # far less likely
    polite = _form(recognizer, "reach to the right please")  # the same meaning, a word more
    assert decided(6.1, polite) is not None


@pytest.mark.unit
def test_a_reverberant_utterance_is_judged_by_the_reverberant_limits(
    recognizer: OfflineRecognizer, synthesize: Synthesize, in_room: Callable[[np.ndarray, float], np.ndarray]
) -> None:
    """ "are you a robot" across a room: Moonshine wrote it word for word, both pocketsphinx passes
    heard "move forward", and Moonshine put "can you move forward" at regret 10. Straight into the
    microphone that verified form is a command; across a room pocketsphinx is too often wrong."""
    polite = _form(recognizer, "can you move forward")
    acceptance = recognizer.config.acceptance

    def verified(fall_ms: float) -> FormScore | None:
        evidence = Evidence(
            99.0, [FormScore(polite, -14.0, 10.0)], "Are you a robot?", "move forward", [], fall_ms
        )
        return recognizer.decide(evidence, acceptance, lambda: "move forward")

    assert verified(40.0) is not None
    assert verified(acceptance.reverberant_from_fall_ms + 20.0) is None
    # The evidence tells the room: the same words straight in, and with a tail decaying 60 dB in 0.5 s.
    speech = np.frombuffer(synthesize("look up", "en-us+m7"), dtype="<i2")
    room = in_room(speech, 0.5).astype("<i2")
    assert recognizer.evidence(speech).fall_ms < acceptance.reverberant_from_fall_ms
    assert recognizer.evidence(room).fall_ms > acceptance.reverberant_from_fall_ms


@pytest.mark.unit
@pytest.mark.parametrize("voice", ["en-us+m7", "en-us+f3", "en-gb+m8"])
def test_what_time_is_it_now_is_the_time_question(
    recognizer: OfflineRecognizer, synthesize: Synthesize, voice: str
) -> None:
    """Moonshine writes it word for word ("What time is it now?"); with no form for it, "what time
    is it" paid the end regret for "now" and the question was never caught."""
    result = recognizer.recognize(synthesize("what time is it now", voice), RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.QUESTION, "time"), result


def _candidate(
    recognizer: OfflineRecognizer, score: FormScore, per_frame: float, grammar: SpokenForm | None = None
) -> Candidate:
    words = recognizer.forms[score.index].words
    agrees = grammar is not None and recognizer._meaning(score) == (grammar.kind, grammar.canonical)
    return Candidate(score, Alignment(100 * per_frame, 100), len(words.split()), agrees)


@pytest.mark.unit
def test_a_form_moonshine_wrote_word_for_word_is_not_overruled_on_alignments_alone(
    recognizer: OfflineRecognizer,
) -> None:
    """ "Please look up." written exactly was taken as `lookout`: pocketsphinx aligned "please look
    out" better, and its regret was within Moonshine's near limit. Only pocketsphinx's grammar
    hearing the other meaning overrules a word-for-word transcript ("move full right", written
    "Move forward")."""
    look_up, look_out = _form(recognizer, "please look up"), _form(recognizer, "please look out")
    acceptance = recognizer.config.acceptance

    def decided(free_text: str, grammar_text: str) -> str:
        grammar = next((f for f in recognizer.forms if f.words == grammar_text), None)
        written, other = FormScore(look_up, -2.0, 0.0), FormScore(look_out, -3.5, 1.5)
        candidates = [
            _candidate(recognizer, written, -2.0, grammar),
            _candidate(recognizer, other, -0.8, grammar),
        ]
        assert recognizer._meaning(rescore(candidates, acceptance.rerank)[0].score)[1] == "lookout"
        evidence = Evidence(40.0, [written, other], free_text, grammar_text, candidates)
        chosen = recognizer.decide(evidence, acceptance, lambda: grammar_text)
        return "" if chosen is None else recognizer._meaning(chosen)[1]

    assert decided("Please look up.", "") == "lookup"
    assert decided("Please look up.", "reach to the") == "lookup"
    assert decided("Please look up.", "look out") == "lookout"  # the grammar heard it: overruled
    assert decided("Please lock up.", "") == "lookout"  # not written word for word: reranked


@pytest.mark.unit
def test_a_command_that_moves_the_base_needs_positive_evidence(recognizer: OfflineRecognizer) -> None:
    """ "bumper" in heavy noise was taken as `turn@back` (the base turns 180 degrees): Moonshine
    wrote nothing, pocketsphinx heard "bumper", and pocketsphinx's alignment of "turn back" carried
    the reranking. A base command is taken only when Moonshine wrote a word of it or pocketsphinx's
    grammar heard it; a head movement needs no more than before."""
    turn_back, bumper, look_up = (_form(recognizer, w) for w in ("turn back", "bumper", "look up"))
    acceptance = recognizer.config.acceptance
    noisy = acceptance.noisy_below_snr_db - 8.0

    def decided(index: int, free_text: str, grammar_text: str) -> str:
        grammar = next((f for f in recognizer.forms if f.words == grammar_text), None)
        taken, heard = FormScore(index, -6.0, 5.0), FormScore(bumper, -8.0, 6.0)
        candidates = [
            _candidate(recognizer, taken, -0.9, grammar),
            _candidate(recognizer, heard, -1.8, grammar),
        ]
        evidence = Evidence(noisy, [taken, heard], free_text, grammar_text, candidates)
        chosen = recognizer.decide(evidence, acceptance, lambda: "")
        return "" if chosen is None else recognizer._meaning(chosen)[1]

    assert decided(turn_back, "", "bumper") == ""
    assert decided(turn_back, "", "") == ""  # pocketsphinx heard nothing: no evidence either
    assert decided(turn_back, "", "turn back") == "turn@back"  # pocketsphinx's grammar heard it
    assert decided(turn_back, "Turn black.", "bumper") == "turn@back"  # Moonshine wrote a word of it
    assert decided(look_up, "", "bumper") == "lookup"  # the head: as before


@pytest.mark.unit
def test_a_stop_phrase_is_never_taken_as_a_question(recognizer: OfflineRecognizer) -> None:
    """ "halt" was answered with what the robot can do (heard as "help"). A question gives way to a
    stop phrase pocketsphinx's grammar heard, or that Moonshine finds nearly as likely and near
    enough to be heard: stop outranks everything. Nearly as likely but further than that, neither
    is taken (chat: "how old are you" put "stop" at 9.9 and the question at 11.4)."""
    help_, halt = _form(recognizer, "help"), _form(recognizer, "halt")
    acceptance = recognizer.config.acceptance
    apart, phrase_max_regret = acceptance.stop_over_question_regret, acceptance.clean.phrase_max_regret

    def decided(
        help_regret: float, halt_regret: float, grammar_text: str
    ) -> tuple[RecognitionKind, str] | None:
        forms = [FormScore(help_, -1.0, help_regret), FormScore(halt, -6.0, halt_regret)]
        evidence = Evidence(40.0, forms, "", grammar_text, [])
        chosen = recognizer.decide(evidence, acceptance, lambda: grammar_text)  # verified
        return None if chosen is None else recognizer._meaning(chosen)

    stop, capabilities = (RecognitionKind.PHRASE, "stop"), (RecognitionKind.QUESTION, "capabilities")
    assert decided(0.0, apart - 0.5, "help") == stop
    # Nearly as likely, but not near enough to be heard: neither.
    assert decided(phrase_max_regret - 1.0, phrase_max_regret + 0.5, "help") is None
    assert decided(0.0, apart + 0.5, "help") == capabilities  # "help", said clearly: "halt" far behind
    assert decided(0.0, 14.0, "halt") == stop  # pocketsphinx heard it
