"""MoonshineScorer and its tokenizer on the model shipped in the moonshine-cpp wheel."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from by_your_command.local_speech.moonshine import (
    FormScore,
    ModelUnavailableError,
    MoonshineConfig,
    MoonshineScorer,
    default_model_dir,
)
from by_your_command.local_speech.tokenizer import END, FIRST_BYTE, SPACE, Tokenizer

Synthesize = Callable[[str, str], bytes]
FORMS = ["move back", "move forward", "reach", "reach left", "look up", "lookup"]


@pytest.fixture(scope="module")
def scorer() -> MoonshineScorer:
    return MoonshineScorer(FORMS)


def _score(scorer: MoonshineScorer, pcm: bytes) -> list[FormScore]:
    return scorer.score(np.frombuffer(pcm, dtype="<i2").astype(np.float32) / 32768.0)


@pytest.mark.unit
def test_the_model_tokenizer_writes_forms_as_the_model_does() -> None:
    tokenizer = Tokenizer.from_file(default_model_dir() / "tokenizer.bin")
    ids = tokenizer.encode("Look up to the left")
    assert len(ids) == 5  # one token per word, as Moonshine itself writes this sentence
    assert tokenizer.decode(ids) == "Look up to the left"
    assert tokenizer.decode(tokenizer.encode("Ten hut, snowman \u2603?")) == "Ten hut, snowman \u2603?"


def _toy(pieces: list[str]) -> Tokenizer:
    return Tokenizer(
        [b"<unk>", b"<s>", b"</s>", *(bytes([i]) for i in range(256)), *(p.encode() for p in pieces)]
    )


@pytest.mark.unit
def test_bpe_merges_the_lowest_id_pair_first_and_falls_back_to_bytes() -> None:
    first = 259  # ids of the pieces below: 259, 260, 261
    tokenizer = _toy(["bc", f"{SPACE}a", f"{SPACE}ab"])
    # "bc" (259) merges before "▁a" (260); left-to-right would have made "▁ab" + "c".
    assert tokenizer.encode("abc") == [first + 1, first]
    assert tokenizer.encode("z") == [FIRST_BYTE + byte for byte in f"{SPACE}z".encode()]
    assert tokenizer.decode(tokenizer.encode("a z")) == "a z"


@pytest.mark.unit
def test_a_broken_tokenizer_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "tokenizer.bin"
    path.write_bytes(b"\x05<unk>\x03<s>\x09</s")  # the last entry promises more bytes than follow
    with pytest.raises(ValueError, match="truncated"):
        Tokenizer.from_file(path)
    path.write_bytes(b"\x01a" * 10)
    with pytest.raises(ValueError, match="more than"):
        Tokenizer.from_file(path)


@pytest.mark.unit
def test_the_form_spoken_scores_best_with_no_regret(scorer: MoonshineScorer, synthesize: Synthesize) -> None:
    scores = _score(scorer, synthesize("move back", "en-029"))
    assert FORMS[scores[0].index] == "move back"
    assert scores[0].regret < 1.0 and scores[0].logprob < 0.0
    assert [s.logprob for s in scores] == sorted((s.logprob for s in scores), reverse=True)


@pytest.mark.unit
def test_a_sentence_that_only_starts_like_a_form_pays_where_it_goes_on(
    scorer: MoonshineScorer, synthesize: Synthesize
) -> None:
    scores = _score(scorer, synthesize("reach for the stars", "en-029"))
    assert FORMS[scores[0].index] == "reach"
    assert scores[0].regret > 4.0


@pytest.mark.unit
def test_a_missing_model_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ModelUnavailableError, match="lacks"):
        MoonshineScorer(FORMS, MoonshineConfig(model_dir=str(tmp_path)))
    for name in ("encoder_model.ort", "decoder_model_merged.ort", "tokenizer.bin"):
        (tmp_path / name).write_bytes(b"not a model")
    with pytest.raises(ModelUnavailableError, match="cannot load"):
        MoonshineScorer(FORMS, MoonshineConfig(model_dir=str(tmp_path)))


class _Heard:
    """A stand-in for Moonshine's decoder that "hears" one sentence: at each position the
    sentence's next token (END after it) is `sure` nats above every other token; off the
    sentence, END is. The decoder's cache carries each row's tokens so far."""

    def __init__(self, tokenizer: Tokenizer, sentence: str, sure: float = 20.0) -> None:
        self.tokens = tokenizer.encode(sentence)
        self.size = len(tokenizer)
        self.sure = sure

    def step(
        self,
        hidden: np.ndarray,
        tokens: np.ndarray,
        past: dict[str, np.ndarray] | None,
        cache: dict[str, np.ndarray] | None,
    ) -> dict[str, np.ndarray]:
        history = (
            tokens if past is None else np.concatenate([past["past_key_values.0.decoder.key"], tokens], 1)
        )
        logits = np.zeros((len(history), 1, self.size), dtype=np.float32)
        for row, seen in enumerate(history):
            written = [int(token) for token in seen[1:]]  # after START
            on_track = written == self.tokens[: len(written)]
            following = self.tokens[len(written)] if on_track and len(written) < len(self.tokens) else END
            logits[row, 0, following] = self.sure
        return {"logits": logits, "present.0.decoder.key": history, "present.0.encoder.key": np.zeros(1)}


def _hearing(scorer: MoonshineScorer, sentence: str, monkeypatch: pytest.MonkeyPatch) -> None:
    class Encoder:
        def run(self, _names: object, _feeds: object) -> list[np.ndarray]:
            return [np.zeros((1, 4, 416), dtype=np.float32)]

    monkeypatch.setattr(scorer, "_encoder", Encoder())
    monkeypatch.setattr(scorer, "_step", _Heard(scorer.tokenizer, sentence).step)


SILENCE = np.zeros(16000, dtype=np.float32)  # the stand-in decoder hears its sentence in anything


@pytest.fixture
def small_scorer() -> MoonshineScorer:
    return MoonshineScorer(["look up", "look up to the left", ("ten hut", "10 hut")])


@pytest.mark.unit
def test_a_final_mark_ends_a_form_only_if_the_transcript_ends_after_it(
    small_scorer: MoonshineScorer, monkeypatch: pytest.MonkeyPatch
) -> None:
    _hearing(small_scorer, "Look up.", monkeypatch)
    best = small_scorer.score(SILENCE)[0]
    assert (best.index, best.regret) == (0, pytest.approx(0.0))
    # "Look up. To the left.": a period, then more words. The period is no end of "look up".
    _hearing(small_scorer, "Look up. To the left.", monkeypatch)
    scores = {score.index: score for score in small_scorer.score(SILENCE)}
    assert scores[0].regret > 7.0
    # A final comma ends a form too (a voice whose pitch does not fall), a comma inside does not.
    _hearing(small_scorer, "Look up,", monkeypatch)
    best = small_scorer.score(SILENCE)[0]
    assert (best.index, best.regret) == (0, pytest.approx(0.0))
    _hearing(small_scorer, "Look up, to the left.", monkeypatch)
    scores = {score.index: score for score in small_scorer.score(SILENCE)}
    assert scores[0].regret > 7.0


@pytest.mark.unit
def test_the_free_transcript_comes_with_the_forms(
    small_scorer: MoonshineScorer, monkeypatch: pytest.MonkeyPatch
) -> None:
    _hearing(small_scorer, "Reach for the stars.", monkeypatch)
    analysis = small_scorer.analyse(SILENCE)
    assert analysis.free.text == "Reach for the stars."
    assert analysis.free.ended and analysis.free.logprob == pytest.approx(0.0, abs=0.01)
    assert analysis.forms and min(score.regret for score in analysis.forms) > 7.0
    _hearing(small_scorer, " ".join(["and then"] * 12), monkeypatch)
    assert not small_scorer.analyse(SILENCE).free.ended  # longer than any form: cut


@pytest.mark.unit
def test_a_form_scores_as_its_best_written_way(
    small_scorer: MoonshineScorer, monkeypatch: pytest.MonkeyPatch
) -> None:
    _hearing(small_scorer, "10 hut", monkeypatch)  # how Moonshine often writes "ten hut"
    best = small_scorer.score(SILENCE)[0]
    assert (best.index, best.regret) == (2, pytest.approx(0.0))
