"""How well each spoken form explains an utterance, by the Moonshine base (English) speech model.

The model files ship inside the `moonshine-cpp` wheel (MIT; encoder, decoder and tokenizer in ORT
format, ~63 MB); they are located with find_spec, never imported (the package's own module loads a
second copy of onnxruntime), and run through this project's onnxruntime. Nothing is downloaded.

Moonshine is an encoder-decoder transcriber: given the audio, the decoder gives the probability of
each next text token. Instead of transcribing freely and then matching text, the decoder is walked
through a trie of the spoken forms' token sequences (a beam search restricted to the forms), so the
answer is always a form, with two numbers:

- `logprob`: log P(form as the whole transcript | audio), its end included (end of text, or a
  final ".", "?" or "!");
- `regret`: at each token, how much more likely the model's own top choice was than the form's
  token, summed. 0 means a free transcription would have written exactly this form; chat that only
  starts like a form ("reach for the stars" for "reach") pays at the token where it goes on.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import onnxruntime

from by_your_command.offline.tokenizer import END, START, Tokenizer

SAMPLE_RATE = 16000
PACKAGE = "moonshine-cpp"
MODEL_FILES = ("encoder_model.ort", "decoder_model_merged.ort", "tokenizer.bin")
LAYERS, HEADS, HEAD_DIM = 8, 8, 52  # Moonshine base
FINAL_MARKS = (".", "?", "!")  # a transcript may end with one of these instead of END

FloatArray = npt.NDArray[np.float32]


class ModelUnavailableError(RuntimeError):
    pass


def default_model_dir() -> Path:
    """The base-en model inside the installed moonshine-cpp wheel (without importing it)."""
    spec = importlib.util.find_spec("moonshine_cpp")
    if spec is None or not spec.submodule_search_locations:
        raise ModelUnavailableError(f"the {PACKAGE} package is not installed (`pip install {PACKAGE}`)")
    return Path(next(iter(spec.submodule_search_locations))) / "models" / "base-en"


@dataclass(frozen=True)
class MoonshineConfig:
    model_dir: str = ""  # "" = the model shipped in the moonshine-cpp wheel
    threads: int = 1  # onnxruntime intra-op threads (the agent shares a small CPU)
    beam: int = 4  # partial forms kept per decoder step
    # Partial forms further than this below the best finished form are dropped: runners-up
    # within it are still scored (the ambiguity check needs them), beyond it they cannot matter.
    window: float = 12.0
    max_tokens: int = 16  # no spoken form is longer

    def __post_init__(self) -> None:
        if self.threads < 1 or self.beam < 1 or self.max_tokens < 1 or self.window <= 0:
            raise ValueError("threads, beam, max_tokens and window must be positive")


@dataclass(frozen=True)
class FormScore:
    index: int  # into the texts the scorer was built with
    logprob: float
    regret: float


@dataclass
class _Node:
    children: dict[int, _Node] = field(default_factory=dict)
    ends: list[int] = field(default_factory=list)  # indices of the texts ending here


@dataclass(frozen=True)
class _Partial:
    logprob: float
    regret: float
    node: _Node
    row: int  # its row in the last decoder output
    token: int  # its last token, fed to the next decoder step


def _log_softmax(logits: npt.NDArray[Any]) -> npt.NDArray[np.float64]:
    values = logits.astype(np.float64)
    return values - np.logaddexp.reduce(values, axis=-1, keepdims=True)


def _as_past(outputs: dict[str, FloatArray], part: str) -> dict[str, FloatArray]:
    """The decoder's `present.*` outputs of one part, named as next step's `past_key_values.*`."""
    return {
        name.replace("present.", "past_key_values.", 1): value
        for name, value in outputs.items()
        if name.startswith("present.") and part in name
    }


def _as_written(text: str) -> str:
    """How the model writes a spoken form: a capital first letter ("look up" -> "Look up")."""
    return text[:1].upper() + text[1:]


class MoonshineScorer:
    """Scores a fixed set of texts against utterances. Not thread-safe (the caller locks)."""

    def __init__(self, texts: Sequence[str], config: MoonshineConfig | None = None) -> None:
        self.config = config or MoonshineConfig()
        directory = Path(self.config.model_dir) if self.config.model_dir else default_model_dir()
        missing = [name for name in MODEL_FILES if not (directory / name).is_file()]
        if missing:
            raise ModelUnavailableError(f"{directory} lacks {missing}")
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = self.config.threads
        options.inter_op_num_threads = 1
        providers = ["CPUExecutionProvider"]
        try:  # an onnxruntime too old for these ORT-format files fails here, not mid-utterance
            self._encoder = onnxruntime.InferenceSession(
                str(directory / MODEL_FILES[0]), sess_options=options, providers=providers
            )
            self._decoder = onnxruntime.InferenceSession(
                str(directory / MODEL_FILES[1]), sess_options=options, providers=providers
            )
            self.tokenizer = Tokenizer.from_file(directory / MODEL_FILES[2])
        except Exception as error:
            raise ModelUnavailableError(f"cannot load the model in {directory}: {error}") from error
        self._outputs = [output.name for output in self._decoder.get_outputs()]
        self._ends = [END, *(i for i in map(self.tokenizer.piece, FINAL_MARKS) if i is not None)]
        self._root = _Node()
        for index, text in enumerate(texts):
            node = self._root
            for token in self.tokenizer.encode(_as_written(text)):
                node = node.children.setdefault(token, _Node())
            node.ends.append(index)

    def score(self, audio: FloatArray) -> list[FormScore]:
        """Finished forms, best first, for 16 kHz mono float audio in [-1, 1]."""
        hidden = self._encoder.run(None, {"input_values": audio.reshape(1, -1).astype(np.float32)})[0]
        first = self._step(hidden, np.array([[START]], dtype=np.int64), None, None)
        cache = _as_past(first, ".encoder.")  # fixed for the whole utterance
        past = _as_past(first, ".decoder.")
        scores = _log_softmax(first["logits"][:, -1])
        partials = [_Partial(0.0, 0.0, self._root, 0, START)]
        finished: dict[int, FormScore] = {}
        for _ in range(self.config.max_tokens):
            candidates: list[_Partial] = []
            for partial in partials:
                row = scores[partial.row]
                top = float(row.max())
                if partial.node.ends:
                    end = max(float(row[token]) for token in self._ends)
                    for index in partial.node.ends:
                        done = FormScore(index, partial.logprob + end, partial.regret + top - end)
                        if index not in finished or done.logprob > finished[index].logprob:
                            finished[index] = done
                for token, child in partial.node.children.items():
                    value = float(row[token])
                    candidates.append(
                        _Partial(
                            partial.logprob + value, partial.regret + top - value, child, partial.row, token
                        )
                    )
            floor = max((done.logprob for done in finished.values()), default=-np.inf) - self.config.window
            candidates = sorted((c for c in candidates if c.logprob > floor), key=lambda c: -c.logprob)
            partials = candidates[: self.config.beam]
            if not partials:
                break
            rows = np.array([partial.row for partial in partials])
            tokens = np.array([[partial.token] for partial in partials], dtype=np.int64)
            out = self._step(hidden, tokens, {name: value[rows] for name, value in past.items()}, cache)
            past = _as_past(out, ".decoder.")
            scores = _log_softmax(out["logits"][:, -1])
            partials = [_Partial(p.logprob, p.regret, p.node, row, p.token) for row, p in enumerate(partials)]
        return sorted(finished.values(), key=lambda score: -score.logprob)

    def _step(
        self,
        hidden: FloatArray,
        tokens: npt.NDArray[np.int64],
        past: dict[str, FloatArray] | None,
        cache: dict[str, FloatArray] | None,
    ) -> dict[str, FloatArray]:
        """One decoder call. The first (past None) computes the encoder attention cache; later
        calls reuse it with batch 1 (broadcast over the partial forms)."""
        feeds: dict[str, Any] = {
            "input_ids": tokens,
            "encoder_hidden_states": hidden,
            "use_cache_branch": np.array([past is not None]),
        }
        if past is None or cache is None:
            empty = np.zeros((1, HEADS, 0, HEAD_DIM), dtype=np.float32)
            for layer in range(LAYERS):
                for part in ("decoder", "encoder"):
                    for kind in ("key", "value"):
                        feeds[f"past_key_values.{layer}.{part}.{kind}"] = empty
        else:
            feeds.update(past)
            feeds.update(cache)
        return dict(zip(self._outputs, self._decoder.run(None, feeds), strict=True))
