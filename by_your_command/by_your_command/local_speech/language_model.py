"""The decoder's language: the spoken forms as word chains, with a garbage loop of filler words.

Written as an ARPA bigram model rather than a JSGF grammar because pocketsphinx searches an n-gram
model with a lexicon tree: a JSGF grammar with a garbage loop took 3-11 s per utterance (phone or
word loop), this model takes about 0.07 x real time. Shape of the model:

- from the start, a spoken form's first word (probability 1 - garbage_start, shared among them),
  or any word at all through the back-off (garbage_start);
- inside a form, its next word (1 - garbage_escape), or any word through the back-off;
- every word alone has the same unigram probability, so garbage is a loop of any words.

Only a hypothesis that is exactly one spoken form counts; anything else is rejected. A bare
grammar (`jsgf_grammar`, the baseline) has no way to say "none of these".
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass

START, END = "<s>", "</s>"


@dataclass(frozen=True)
class GarbageWeights:
    garbage_start: float = 0.05  # chance an utterance starts as garbage instead of a form
    garbage_escape: float = 0.01  # chance a form is left for garbage after each word
    end: float = 0.5  # unigram probability of the utterance end

    def __post_init__(self) -> None:
        for name in ("garbage_start", "garbage_escape", "end"):
            value = getattr(self, name)
            if not 0.0 < value < 1.0:
                raise ValueError(f"{name} must lie strictly between 0 and 1, got {value}")


def _log10(probability: float) -> str:
    return f"{math.log10(probability):.4f}"


def arpa_model(forms: Iterable[str], filler_words: Iterable[str], weights: GarbageWeights) -> str:
    """The ARPA text of the model; `forms` are lower-case word strings."""
    successors: dict[str, set[str]] = defaultdict(set)
    words: set[str] = set(filler_words)
    for form in forms:
        chain = [START, *form.split(), END]
        words.update(chain[1:-1])
        for before, after in zip(chain[:-1], chain[1:], strict=True):
            successors[before].add(after)
    if not successors:
        raise ValueError("no spoken forms: nothing to recognize")
    unigram = _log10(1.0 / len(words))
    escape = _log10(weights.garbage_escape)
    lines = ["\\data\\", f"ngram 1={len(words) + 2}"]
    lines += [f"ngram 2={sum(len(after) for after in successors.values())}", "", "\\1-grams:"]
    lines.append(f"-99.0000 {START} {_log10(weights.garbage_start)}")
    lines.append(f"{_log10(weights.end)} {END}")
    lines += [f"{unigram} {word} {escape}" for word in sorted(words)]
    lines += ["", "\\2-grams:"]
    for before in sorted(successors):
        left = weights.garbage_start if before == START else weights.garbage_escape
        share = _log10((1.0 - left) / len(successors[before]))
        lines += [f"{share} {before} {after}" for after in sorted(successors[before])]
    return "\n".join([*lines, "", "\\end\\", ""])


def jsgf_grammar(forms: Iterable[str]) -> str:
    """A bare JSGF grammar of the forms: every utterance is forced into one (the baseline)."""
    alternatives = " | ".join(sorted(set(forms)))
    if not alternatives:
        raise ValueError("no spoken forms: nothing to recognize")
    return f"#JSGF V1.0;\ngrammar commands;\npublic <utterance> = {alternatives};\n"
