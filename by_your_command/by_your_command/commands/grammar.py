"""Parse what an LLM emitted into robot commands, tolerating how LLMs actually write.

Grammar of one command (case-insensitive): `base` or `base@modifier`, where base is an arm preset,
a behavior or a bare bearing (a bare bearing means `pan@bearing`); the modifier is a bearing, a
numeric angle in degrees or, for label commands (follow/track), a short label.

Tolerated around it: code fences, list bullets, quotes and surrounding punctuation, "COMMAND:"-like
prefixes, and several commands in one message separated by newlines, commas or semicolons.
Everything else is rejected with a reason; nothing is dropped without one.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from by_your_command.commands.vocabulary import CommandSpec, ModifierKind, ModifierUse, Vocabulary

# Prefixes LLMs put before a command ("PRESET: lookup", "Command: stop").
PREFIXES = ("command", "commands", "cmd", "preset", "arm", "behavior", "behaviour", "action", "robot")
MAX_COMMAND_CHARS = 80
MAX_LABEL_CHARS = 40
MAX_PIECES = 20  # a chatty paragraph on response_cmd must not flood command_status

_PREFIX = re.compile(r"^(?:" + "|".join(PREFIXES) + r")\s*:\s*", re.IGNORECASE)
_BULLET = re.compile(r"^(?:[-*+\u2022]|\d{1,2}[.)])\s+")
_SEPARATORS = re.compile(r"[\n\r,;]+|[.!?]\s+")  # ". " ends a sentence; "-0.5" keeps its point
_EDGE_PUNCTUATION = " \t\"'`.!?:*_()[]{}<>"
_LABEL = re.compile(r"^[a-z0-9][a-z0-9 _-]*$")


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


def _is_stop(parsed: Parsed) -> bool:
    return parsed.command is not None and parsed.command.base == "stop"


def _format_angle(value: float) -> str:
    text = repr(value + 0.0)  # + 0.0 turns -0.0 into 0.0
    return text[:-2] if text.endswith(".0") else text


class CommandGrammar:
    def __init__(self, vocabulary: Vocabulary) -> None:
        self.vocabulary = vocabulary
        self._pan = vocabulary.commands.get("pan")

    # -- messages -------------------------------------------------------------------------------
    def parse_message(self, message: str) -> list[Parsed]:
        """Every command-like piece of `message`, each accepted or rejected with a reason."""
        lines = [line.strip() for line in message.splitlines() if not line.strip().startswith("```")]
        if "\n".join(lines).strip().startswith(("{", "[")):
            return [Parsed(message.strip(), None, "structured data (JSON), not a command")]
        # Bullets go first: "1. lookup" must not split at its ". " like a sentence end.
        body = "\n".join(_BULLET.sub("", line) for line in lines)
        pieces = [piece.strip() for piece in _SEPARATORS.split(body)]
        pieces = [piece for piece in pieces if piece.strip(_EDGE_PUNCTUATION + "-")]
        parsed = [self.parse_one(piece) for piece in pieces[:MAX_PIECES]]
        if len(pieces) > MAX_PIECES:
            # A stop is never lost, however chatty the message; the rest is reported in one verdict.
            stops = [result for result in map(self.parse_one, pieces[MAX_PIECES:]) if _is_stop(result)]
            skipped = len(pieces) - MAX_PIECES - len(stops)
            reason = f"{skipped} more pieces after the first {MAX_PIECES} were not examined"
            parsed += [*stops, Parsed(" ".join(pieces[MAX_PIECES:])[:200], None, reason)]
        return parsed or [Parsed(message.strip(), None, "empty message: no command found")]

    # -- one command ----------------------------------------------------------------------------
    def parse_one(self, raw: str) -> Parsed:
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
        while text != previous:  # peel bullets, prefixes and punctuation in any order
            previous = text
            text = _BULLET.sub("", text)
            text = _PREFIX.sub("", text)
            text = text.strip(_EDGE_PUNCTUATION)
        return " ".join(text.lower().split())

    def _bearing(self, text: str) -> str | None:
        name = re.sub(r"[\s_]+", "-", text)
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
