"""The robot's tools as the offline recognizer hears them: each declared phrase ("go to the
kitchen") with the call it makes (`go_to`, `{"place": "kitchen"}`).

The phrases come from the tool catalog (tools.yaml `spoken:`, over the bridge: untrusted), so they
are normalised and bounded here before any of them reaches the decoder: at most `max_phrases`, each
of plain words and at most `max_words` of them (Moonshine scores forms of up to 16 tokens, and
a polite opening and closing add up to three words), arguments a small JSON object. What is left
out is counted by reason and named in a warning; nothing is dropped silently.
"""

from __future__ import annotations

import json
import logging
import re
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

_WORD = re.compile(r"^[a-z]+(?:'[a-z]+)?$")
_EDGE = ' \t.,;:!?"`'
_NAME = re.compile(r"^[a-zA-Z][a-zA-Z0-9_]{0,63}$")  # a catalog tool name
MAX_ARGUMENTS_CHARS = 1000
MAX_NAMED = 8  # phrases named in one warning; the rest are counted


# Why a phrase was left out (the keys of the counters).
TOO_MANY = "too many phrases"
TOO_LONG = "too long"
NOT_WORDS = "not plain words"
BAD_TOOL = "bad tool name or arguments"
AMBIGUOUS = "said for two different calls"
NOT_IN_DICTIONARY = "a word not in the pronunciation dictionary"
TAKEN = "already a command, phrase or question"


@dataclass(frozen=True)
class ToolPhrase:
    words: str  # lower-case plain words separated by single spaces
    tool: str
    arguments: str  # a JSON object, keys sorted: the same call is always the same text

    @property
    def canonical(self) -> str:
        """What a Recognition of it carries: `go_to {"place": "kitchen"}` (a tool name has no space)."""
        return f"{self.tool} {self.arguments}"


def tool_call(canonical: str) -> tuple[str, str]:
    """(tool name, arguments JSON) of a tool phrase's canonical string."""
    name, _, arguments = canonical.partition(" ")
    return name, arguments or "{}"


@dataclass(frozen=True)
class PhraseLimits:
    max_phrases: int = 512
    max_words: int = 8
    max_chars: int = 80

    def __post_init__(self) -> None:
        if not (1 <= self.max_phrases <= 4096 and 1 <= self.max_words <= 12 and 1 <= self.max_chars <= 200):
            raise ValueError("need max_phrases in [1, 4096], max_words in [1, 12], max_chars in [1, 200]")


@dataclass
class Selection:
    phrases: tuple[ToolPhrase, ...] = ()
    cut: Counter[str] = field(default_factory=Counter)  # reason -> phrases left out


def words_of(phrase: str) -> str:
    """A phrase as the recognizer's words: lower case, `-` and `_` as spaces, edge punctuation off."""
    text = phrase.lower().replace("-", " ").replace("_", " ")
    return " ".join(part.strip(_EDGE) for part in text.split() if part.strip(_EDGE))


def select_phrases(declared: Iterable[tuple[str, str, str]], limits: PhraseLimits | None = None) -> Selection:
    """The usable phrases of (tool, phrase, arguments JSON) triples, in their order; the first
    `max_phrases` usable ones are kept. A phrase said for two different calls is left out for both:
    neither is what the user surely meant."""
    limits = limits or PhraseLimits()
    selection = Selection()
    named: dict[str, list[str]] = {}
    meanings: dict[str, ToolPhrase] = {}
    ambiguous: set[str] = set()

    def leave_out(reason: str, phrase: str) -> None:
        selection.cut[reason] += 1
        named.setdefault(reason, []).append(phrase[:80])

    for tool, phrase, arguments in declared:
        if len(phrase) > limits.max_chars * 2:
            leave_out(TOO_LONG, phrase)
            continue
        words = words_of(phrase)
        if not words or not all(_WORD.match(word) for word in words.split()):
            leave_out(NOT_WORDS, phrase)
            continue
        if len(words) > limits.max_chars or len(words.split()) > limits.max_words:
            leave_out(TOO_LONG, phrase)
            continue
        canonical_arguments = _arguments(arguments)
        if canonical_arguments is None or not _NAME.match(tool):
            leave_out(BAD_TOOL, phrase)
            continue
        candidate = ToolPhrase(words, tool, canonical_arguments)
        known = meanings.get(words)
        if known is None:
            meanings[words] = candidate
        elif known != candidate:
            ambiguous.add(words)
    for said in sorted(ambiguous):
        leave_out(AMBIGUOUS, said)
    usable = [phrase for said, phrase in meanings.items() if said not in ambiguous]
    for extra in usable[limits.max_phrases :]:
        leave_out(TOO_MANY, extra.words)
    selection.phrases = tuple(usable[: limits.max_phrases])
    for reason, left_out in named.items():
        warn_left_out(reason, left_out)
    return selection


def warn_left_out(reason: str, phrases: list[str]) -> None:
    shown = ", ".join(repr(phrase) for phrase in phrases[:MAX_NAMED])
    more = f" and {len(phrases) - MAX_NAMED} more" if len(phrases) > MAX_NAMED else ""
    log.warning("offline: %d tool phrase(s) left out (%s): %s%s", len(phrases), reason, shown, more)


def _arguments(text: str) -> str | None:
    """The arguments as canonical JSON object text, or None when they are not one (or too long)."""
    if len(text) > MAX_ARGUMENTS_CHARS:
        return None
    try:
        data = json.loads(text)
    except ValueError:
        return None
    return json.dumps(data, sort_keys=True) if isinstance(data, dict) else None
