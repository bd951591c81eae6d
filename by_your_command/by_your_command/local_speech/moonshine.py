"""How well each spoken form explains an utterance, by the Moonshine base (English) speech model.

The model files ship inside the `moonshine-cpp` wheel (MIT; encoder, decoder and tokenizer in ORT
format, ~63 MB); they are located with find_spec, never imported (the package's own module loads a
second copy of onnxruntime), and run through this project's onnxruntime. Nothing is downloaded.

Moonshine is an encoder-decoder transcriber: given the audio, the decoder gives the probability of
each next text token. Instead of transcribing freely and then matching text, the decoder is walked
through a trie of the spoken forms' token sequences (a beam search restricted to the forms), so the
answer is always a form, with these numbers:

- `logprob`: log P(form as the whole transcript | audio), its end included: end of text, or a
  final ".", "?", "!" or "," that end of text then follows (a period followed by more words is no end);
- `regret`: at each token, how much more likely the model's own top choice was than the form's
  token, summed. 0 means a free transcription would have written exactly this form; chat that only
  starts like a form ("reach for the stars" for "reach") pays at the token where it goes on;
- `end_regret`: the part of the regret paid for ending there (the model heard more words).

A form may be written several ways (spoken.written_forms: "10 hut", "left-ish"); it scores as its
best. The model's own greedy transcript of the same audio comes along (`analyse`): one more row
of the same decoder calls. The ORT-format files are loaded as ONNX (ort_format.py), so their int8
weights are dequantized once at load instead of on every decoder call.
"""

from __future__ import annotations

import copy
import importlib.util
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import onnxruntime

from by_your_command.local_speech.ort_format import onnx_model
from by_your_command.local_speech.spoken import sentence_case
from by_your_command.local_speech.tokenizer import END, START, Tokenizer

log = logging.getLogger(__name__)

SAMPLE_RATE = 16000
PACKAGE = "moonshine-cpp"
MODEL_FILES = ("encoder_model.ort", "decoder_model_merged.ort", "tokenizer.bin")
LAYERS, HEADS, HEAD_DIM = 8, 8, 52  # Moonshine base
# A transcript may end with one of these instead of END. The comma: speech whose pitch does not
# fall at the end (flite's voices, a speaker listing) is written "Pan full left,"
# (bench/offline_experiments.md).
FINAL_MARKS = (".", "?", "!", ",")

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
    beam: int = 8  # partial forms kept per decoder step
    # Partial forms further than this below the best finished form are dropped: runners-up
    # within it are still scored (the ambiguity check needs them), beyond it they cannot matter.
    window: float = 12.0
    max_tokens: int = 16  # no spoken form is longer
    # Load the ORT-format files as ONNX (ort_format.py): same outputs, a decoder call ~4x faster.
    optimize: bool = True

    def __post_init__(self) -> None:
        if self.threads < 1 or self.beam < 1 or self.max_tokens < 1 or self.window <= 0:
            raise ValueError("threads, beam, max_tokens and window must be positive")


@dataclass(frozen=True)
class FormScore:
    index: int  # into the texts the scorer was built with
    logprob: float
    regret: float
    # The part of `regret` paid for ending there (the final mark and END): large when the model
    # heard more words after the form ("stop by later" as "stop").
    end_regret: float = 0.0


@dataclass(frozen=True)
class Transcript:
    """Moonshine's own greedy transcript (at most max_tokens tokens)."""

    text: str
    logprob: float  # its tokens and its end (when it ended)
    ended: bool  # False: cut at max_tokens, so longer than any form


@dataclass(frozen=True)
class Analysis:
    forms: list[FormScore]  # finished forms, best (highest logprob) first
    free: Transcript


@dataclass
class _Free:
    tokens: list[int] = field(default_factory=list)
    logprob: float = 0.0
    ended: bool = False


@dataclass
class _Node:
    children: dict[int, _Node] = field(default_factory=dict)
    ends: list[int] = field(default_factory=list)  # indices of the texts ending here
    after_mark: _Node | None = None  # where a final mark leads from a node with ends
    marked: bool = False  # a final mark was just written: only END may follow


@dataclass(frozen=True)
class _Partial:
    logprob: float
    regret: float
    node: _Node
    row: int  # its row in the last decoder output
    token: int  # its last token, fed to the next decoder step
    mark_regret: float = 0.0  # regret of the final mark it just wrote (after_mark nodes only)


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


class MoonshineScorer:
    """Scores a fixed set of texts against utterances. Not thread-safe (the caller locks)."""

    def __init__(self, texts: Sequence[str | Sequence[str]], config: MoonshineConfig | None = None) -> None:
        """`texts`: one entry per form, a text or the ways it may be written (spoken.written_forms);
        a form scores as its best-written way, under its entry's index."""
        self.config = config or MoonshineConfig()
        directory = Path(self.config.model_dir) if self.config.model_dir else default_model_dir()
        missing = [name for name in MODEL_FILES if not (directory / name).is_file()]
        if missing:
            raise ModelUnavailableError(f"{directory} lacks {missing}")
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = self.config.threads
        options.inter_op_num_threads = 1
        try:  # an onnxruntime too old for these ORT-format files fails here, not mid-utterance
            self._encoder = self._session(directory / MODEL_FILES[0], options)
            self._decoder = self._session(directory / MODEL_FILES[1], options)
            self.tokenizer = Tokenizer.from_file(directory / MODEL_FILES[2])
        except Exception as error:
            raise ModelUnavailableError(f"cannot load the model in {directory}: {error}") from error
        self._outputs = [output.name for output in self._decoder.get_outputs()]
        self._marks = [i for i in map(self.tokenizer.piece, FINAL_MARKS) if i is not None]
        self._root = self._trie(texts)

    def with_texts(self, texts: Sequence[str | Sequence[str]]) -> MoonshineScorer:
        """A scorer of other texts on the same loaded model (its sessions are shared: onnxruntime
        runs them from several threads; this scorer is left as it is)."""
        other = copy.copy(self)
        other._root = self._trie(texts)
        return other

    def _trie(self, texts: Sequence[str | Sequence[str]]) -> _Node:
        root = _Node()
        for index, text in enumerate(texts):
            for written in [text] if isinstance(text, str) else text:  # its ways of being written
                node = root
                for token in self.tokenizer.encode(sentence_case(written)):  # as the model writes it
                    node = node.children.setdefault(token, _Node())
                if index not in node.ends:
                    node.ends.append(index)
                node.after_mark = _Node(ends=node.ends, marked=True)
        return root

    def _session(self, path: Path, options: onnxruntime.SessionOptions) -> onnxruntime.InferenceSession:
        """The model as ONNX (ort_format.py: its int8 weights dequantized once, at load, instead of
        on every call), or the ORT-format file as shipped if it cannot be rewritten."""
        providers = ["CPUExecutionProvider"]
        if self.config.optimize:
            try:
                model = onnx_model(path.read_bytes())
                return onnxruntime.InferenceSession(model, sess_options=options, providers=providers)
            except Exception as error:  # the file as shipped still works, only slower
                log.warning("running %s as shipped (slower): %s", path.name, error)
        return onnxruntime.InferenceSession(str(path), sess_options=options, providers=providers)

    def score(self, audio: FloatArray) -> list[FormScore]:
        """Finished forms, best first, for 16 kHz mono float audio in [-1, 1]."""
        return self.analyse(audio).forms

    def analyse(self, audio: FloatArray) -> Analysis:
        """The forms (best first) and Moonshine's own free transcript of the same audio: the free
        transcript is one more row of the same decoder calls (greedy), so it costs little."""
        hidden = self._encoder.run(None, {"input_values": audio.reshape(1, -1).astype(np.float32)})[0]
        first = self._step(hidden, np.array([[START]], dtype=np.int64), None, None)
        cache = _as_past(first, ".encoder.")  # fixed for the whole utterance
        past = _as_past(first, ".decoder.")
        scores = _log_softmax(first["logits"][:, -1])
        partials = [_Partial(0.0, 0.0, self._root, 0, START)]
        finished: dict[int, FormScore] = {}
        free = _Free()
        free_row: int | None = 0
        for step in range(self.config.max_tokens + 1):
            candidates: list[_Partial] = []
            for partial in partials:
                row = scores[partial.row]
                top = float(row.max())
                node = partial.node
                if node.ends:
                    # A form ends with END, or with a final mark that END must then follow: a
                    # mark alone is no end ("Look up. To the left." is not "look up").
                    end = float(row[END])
                    for index in node.ends:
                        done = FormScore(
                            index,
                            partial.logprob + end,
                            partial.regret + top - end,
                            partial.mark_regret + top - end,
                        )
                        if index not in finished or done.logprob > finished[index].logprob:
                            finished[index] = done
                    if node.after_mark is not None and self._marks and step < self.config.max_tokens:
                        mark = max(self._marks, key=lambda token: float(row[token]))
                        value = float(row[mark])
                        candidates.append(
                            _Partial(
                                partial.logprob + value,
                                partial.regret + top - value,
                                node.after_mark,
                                partial.row,
                                mark,
                                top - value,
                            )
                        )
                if step == self.config.max_tokens:
                    continue
                for token, child in partial.node.children.items():
                    value = float(row[token])
                    candidates.append(
                        _Partial(
                            partial.logprob + value, partial.regret + top - value, child, partial.row, token
                        )
                    )
            if free_row is not None:
                token = int(np.argmax(scores[free_row]))
                free.logprob += float(scores[free_row][token])
                if token == END:
                    free.ended = True
                    free_row = None
                elif step == self.config.max_tokens:
                    free_row = None  # longer than any form: not finished, and it cannot be one
                else:
                    free.tokens.append(token)
            floor = max((done.logprob for done in finished.values()), default=-np.inf) - self.config.window
            candidates = sorted((c for c in candidates if c.logprob > floor), key=lambda c: -c.logprob)
            partials = candidates[: self.config.beam]
            if not partials and free_row is None:
                break
            rows = [partial.row for partial in partials]
            tokens = [partial.token for partial in partials]
            if free_row is not None:
                rows.append(free_row)
                tokens.append(free.tokens[-1])
                free_row = len(rows) - 1
            out = self._step(
                hidden,
                np.array(tokens, dtype=np.int64).reshape(-1, 1),
                {name: value[np.array(rows)] for name, value in past.items()},
                cache,
            )
            past = _as_past(out, ".decoder.")
            scores = _log_softmax(out["logits"][:, -1])
            partials = [
                _Partial(p.logprob, p.regret, p.node, row, p.token, p.mark_regret)
                for row, p in enumerate(partials)
            ]
        transcript = Transcript(self.tokenizer.decode(free.tokens), free.logprob, free.ended)
        return Analysis(sorted(finished.values(), key=lambda score: -score.logprob), transcript)

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
