"""Parse what an LLM emitted into robot commands, tolerating how LLMs actually write.

Grammar of one command (case-insensitive): `base` or `base@modifier`, where base is an arm preset,
a behavior or a bare bearing (a bare bearing means `pan@bearing`); the modifier is a bearing, a
numeric angle in degrees or, for label commands (follow/track), a short label.

Tolerated around it: code fences, list bullets, quotes and surrounding punctuation, "COMMAND:"-like
prefixes, and several commands in one message separated by newlines, commas or semicolons.
Everything else is rejected with a reason; nothing is dropped without one.

Messages are untrusted, so the work per message is bounded: a message longer than
`max_message_chars` is not parsed (one verdict says so), only the first `max_pieces` pieces are
parsed, a piece is never cleaned for more than MAX_PEEL_ROUNDS rounds nor when it is too long to
be a command, and no regex here can backtrack (no nested or overlapping quantifiers). A `stop` is
still found everywhere, by a linear scan that looks only at the few characters around each "stop".
"""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass

from by_your_command.commands.vocabulary import CommandSpec, ModifierKind, ModifierUse, Vocabulary

# Prefixes LLMs put before a command ("PRESET: lookup", "Command: stop").
PREFIXES = ("command", "commands", "cmd", "preset", "arm", "behavior", "behaviour", "action", "robot")
MAX_COMMAND_CHARS = 80
MAX_LABEL_CHARS = 40
# Longer raw pieces cannot clean down to MAX_COMMAND_CHARS (decoration is a few characters), so
# they are refused before cleaning.
MAX_RAW_PIECE_CHARS = 4 * MAX_COMMAND_CHARS
MAX_PEEL_ROUNDS = 8  # "- COMMAND: PRESET: `lookup`" takes 3; more is not a command anyway
MAX_STOP_CANDIDATES = 64  # occurrences of the word "stop" looked at in what is not parsed
EXCERPT_CHARS = 200  # raw text quoted in a verdict about a whole message or its tail

_PREFIX = re.compile(r"^(?:" + "|".join(PREFIXES) + r")\s*:\s*", re.IGNORECASE)
_BULLET = re.compile(r"^(?:[-*+\u2022]|\d{1,2}[.)])\s+")
_SEPARATORS = re.compile(r"[\n\r,;]+|[.!?]\s+")  # ". " ends a sentence; "-0.5" keeps its point
_EDGE_PUNCTUATION = " \t\"'`.!?:*_()[]{}<>"
_LABEL = re.compile(r"^[a-z0-9][a-z0-9 _-]*$")
_BEARING_GAPS = re.compile(r"[\s_]+")
# "stop" in any case, not inside a word ("__stop__" and "**STOP**" are candidates). Written with
# character classes and the look-behind after the first letter: 3x faster than IGNORECASE and a
# leading look-behind on a 1 MB message.
_STOP_WORD = re.compile(r"[sS](?<![a-zA-Z0-9][sS])[tT][oO][pP](?![a-zA-Z0-9])")
_PIECE_END = re.compile(r"[\n\r,;]|[.!?](?=\s)")  # where _SEPARATORS would split


@dataclass(frozen=True)
class MessageLimits:
    """How much of one message is examined (the command processor's parameters default to these)."""

    max_message_chars: int = 4096  # longer messages get one rejected verdict, unparsed
    max_pieces: int = 20  # pieces (commands or chatter) parsed per message; the rest: one verdict

    def __post_init__(self) -> None:
        if self.max_message_chars < 1 or self.max_pieces < 1:
            raise ValueError("max_message_chars and max_pieces must be >= 1")


@dataclass(frozen=True)
class Command:
    """A valid command in normal form: `base` or `base@modifier`."""

    spec: CommandSpec
    modifier: str = ""

    @property
    def base(self) -> str:
        return self.spec.name

    @property
    def text(self) -> str:
        return f"{self.base}@{self.modifier}" if self.modifier else self.base


class _Refused(ValueError):
    """Raised inside the grammar with the reason a piece of text is not a valid command."""


@dataclass(frozen=True)
class Parsed:
    """One command-like piece of a message: the raw text and either a command or a rejection."""

    raw: str
    command: Command | None
    reason: str  # why it was rejected, or "" when accepted


def is_stop(parsed: Parsed) -> bool:
    return parsed.command is not None and parsed.command.base == "stop"


def _piece_around(text: str, start: int, end: int) -> str | None:
    """The piece of `text` holding text[start:end], or None when it is longer than any command."""
    window_start = max(0, start - MAX_RAW_PIECE_CHARS)
    ends_before = [found.end() for found in _PIECE_END.finditer(text, window_start, start)]
    if ends_before:
        piece_start = ends_before[-1]
    elif window_start == 0:
        piece_start = 0
    else:
        return None
    window_end = min(len(text), end + MAX_RAW_PIECE_CHARS)
    next_end = _PIECE_END.search(text, end, window_end)
    if next_end is not None:
        piece_end = next_end.start()
    elif window_end == len(text):
        piece_end = len(text)
    else:
        return None
    return text[piece_start:piece_end].strip()


def excerpt(text: str) -> str:
    return text if len(text) <= EXCERPT_CHARS else text[:EXCERPT_CHARS] + "…"


def _format_angle(value: float) -> str:
    text = repr(value + 0.0)  # + 0.0 turns -0.0 into 0.0
    return text[:-2] if text.endswith(".0") else text


class CommandGrammar:
    def __init__(self, vocabulary: Vocabulary, limits: MessageLimits | None = None) -> None:
        self.vocabulary = vocabulary
        self.limits = limits or MessageLimits()
        self._pan = vocabulary.commands.get("pan")

    # -- messages -------------------------------------------------------------------------------
    def parse_message(self, message: str) -> list[Parsed]:
        """Every command-like piece of `message`, each accepted or rejected with a reason."""
        limit = self.limits.max_message_chars
        if len(message) > limit:
            # Not parsed: one verdict for the message, and a stop in it still counts.
            reason = f"message of {len(message)} characters is longer than {limit}: not examined"
            stop = self.find_stop(message)
            return [*([stop] if stop else []), Parsed(excerpt(message), None, reason)]
        lines = [line.strip() for line in message.splitlines() if not line.strip().startswith("```")]
        if "\n".join(lines).strip().startswith(("{", "[")):
            return [Parsed(excerpt(message.strip()), None, "structured data (JSON), not a command")]
        # Bullets go first: "1. lookup" must not split at its ". " like a sentence end.
        body = "\n".join(_BULLET.sub("", line) for line in lines)
        pieces = [piece.strip() for piece in _SEPARATORS.split(body)]
        pieces = [piece for piece in pieces if piece.strip(_EDGE_PUNCTUATION + "-")]
        most = self.limits.max_pieces
        parsed = [self.parse_one(piece) for piece in pieces[:most]]
        if len(pieces) > most:
            # A stop is never lost, however chatty the message (one is enough); the rest is reported
            # in one verdict.
            stop = self._first_stop(pieces[most:])
            skipped = len(pieces) - most - (1 if stop else 0)
            reason = f"{skipped} more pieces after the first {most} were not examined"
            parsed += [*([stop] if stop else []), Parsed(excerpt(" ".join(pieces[most:])), None, reason)]
        return parsed or [Parsed(excerpt(message.strip()), None, "empty message: no command found")]

    def find_stop(self, text: str) -> Parsed | None:
        """A piece of `text` that is a `stop` command, found without parsing the rest of it.

        Linear: one regex scan, then the piece around each of the first MAX_STOP_CANDIDATES
        occurrences of the word, bounded by the separators the grammar splits at (a piece with
        no separator within MAX_RAW_PIECE_CHARS of the word is longer than any command).
        """
        words = itertools.islice(_STOP_WORD.finditer(text), MAX_STOP_CANDIDATES)
        return self._first_stop(_piece_around(text, word.start(), word.end()) for word in words)

    def _first_stop(self, pieces: Iterable[str | None]) -> Parsed | None:
        candidates = (piece for piece in pieces if piece is not None and _STOP_WORD.search(piece))
        for piece in itertools.islice(candidates, MAX_STOP_CANDIDATES):
            parsed = self.parse_one(piece)
            if is_stop(parsed):
                return parsed
        return None

    # -- one command ----------------------------------------------------------------------------
    def parse_one(self, raw: str) -> Parsed:
        if len(raw) > MAX_RAW_PIECE_CHARS:
            return Parsed(excerpt(raw), None, f"longer than {MAX_COMMAND_CHARS} characters: not a command")
        text = self._clean(raw)
        if not text:
            return Parsed(raw, None, "empty command")
        if len(text) > MAX_COMMAND_CHARS:
            return Parsed(raw, None, f"longer than {MAX_COMMAND_CHARS} characters: not a command")
        base, at, modifier = (part.strip() for part in text.partition("@"))
        if "@" in modifier:
            return Parsed(raw, None, "more than one '@'")
        try:
            return Parsed(raw, self._build(base, modifier if at else None), "")
        except _Refused as refusal:
            spoken = None if at else self._spoken_form(text)
            return Parsed(raw, spoken, "") if spoken else Parsed(raw, None, str(refusal))

    def _clean(self, raw: str) -> str:
        text = raw.strip()
        previous = None
        for _ in range(MAX_PEEL_ROUNDS):  # peel bullets, prefixes and punctuation in any order
            if text == previous:
                break
            previous = text
            text = _BULLET.sub("", text)
            text = _PREFIX.sub("", text)
            text = text.strip(_EDGE_PUNCTUATION)
        return " ".join(text.lower().split())

    def _bearing(self, text: str) -> str | None:
        name = _BEARING_GAPS.sub("-", text)
        return name if name in self.vocabulary.bearings else None

    def _build(self, base: str, modifier: str | None) -> Command:
        spec = self.vocabulary.commands.get(base)
        if spec is None:
            bearing = self._bearing(base)
            if bearing is not None and modifier is None and self._pan is not None:
                return Command(self._pan, bearing)
            raise _Refused(f"unknown command {base!r}" if base else "missing command before '@'")
        if modifier is None:
            if spec.modifier is ModifierUse.REQUIRED:
                raise _Refused(f"{base!r} needs a modifier: {base}@{self._modifier_hint(spec)}")
            return Command(spec)
        if spec.modifier is ModifierUse.NONE:
            raise _Refused(f"{base!r} takes no modifier")
        return Command(spec, self._modifier(spec, modifier))

    def _spoken_form(self, text: str) -> Command | None:
        """`turn left` / `pan -30` as LLMs say it: a direction command, a space, a direction."""
        base, _, rest = text.partition(" ")
        spec = self.vocabulary.commands.get(base)
        if not rest or spec is None or spec.modifier is ModifierUse.NONE:
            return None
        if spec.modifier_kind is not ModifierKind.DIRECTION:
            return None  # "follow me please" must not become follow@me please
        try:
            return Command(spec, self._modifier(spec, rest))
        except _Refused:
            return None

    def _modifier_hint(self, spec: CommandSpec) -> str:
        return "<label>" if spec.modifier_kind is ModifierKind.LABEL else "<bearing or angle>"

    def _modifier(self, spec: CommandSpec, modifier: str) -> str:
        """The normalised modifier; raises _Refused saying why it is invalid."""
        if not modifier:
            raise _Refused(f"empty modifier after '{spec.name}@'")
        if spec.modifier_kind is ModifierKind.LABEL:
            if len(modifier) > MAX_LABEL_CHARS or not _LABEL.match(modifier):
                allowed = f"letters, digits, spaces, - and _; at most {MAX_LABEL_CHARS}"
                raise _Refused(f"invalid label {modifier!r} ({allowed})")
            return modifier
        bearing = self._bearing(modifier)
        if bearing is not None:
            return bearing
        try:
            angle = float(modifier)
        except ValueError:
            bearings = ", ".join(self.vocabulary.bearings)
            raise _Refused(f"{modifier!r} is neither a bearing ({bearings}) nor an angle") from None
        low, high = self.vocabulary.angle_min, self.vocabulary.angle_max
        if not math.isfinite(angle) or not low <= angle <= high:
            raise _Refused(f"angle {modifier} outside [{_format_angle(low)}, {_format_angle(high)}] degrees")
        return _format_angle(angle)
