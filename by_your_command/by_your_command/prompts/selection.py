"""Which prompt (and user prefix) applies: conditional rules over a context, then the default."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

_COMPARISON = re.compile(r"^\s*([A-Za-z_]\w*)\s*(==|!=|<=|>=|<|>)\s*(.+?)\s*$")
_BARE = re.compile(r"^\s*(not\s+)?([A-Za-z_]\w*)\s*$")


@dataclass(frozen=True)
class Condition:
    """`key == 'text'`, `key != 'text'`, `key < 3`, `key >= 0.5`, `key` or `not key`."""

    key: str
    operator: str  # "truthy", "falsy" or a comparison operator
    value: str | float | None = None

    def holds(self, context: Mapping[str, object]) -> bool:
        if self.operator in ("truthy", "falsy"):
            return bool(context.get(self.key)) == (self.operator == "truthy")
        if self.key not in context:
            return False
        actual = context[self.key]
        if isinstance(self.value, str):
            equal = str(actual) == self.value
            return equal if self.operator == "==" else (not equal if self.operator == "!=" else False)
        if isinstance(actual, bool) or not isinstance(actual, (int, float)) or self.value is None:
            return False
        number = float(actual)
        return {
            "==": number == self.value,
            "!=": number != self.value,
            "<": number < self.value,
            ">": number > self.value,
            "<=": number <= self.value,
            ">=": number >= self.value,
        }[self.operator]


def parse_condition(text: str) -> Condition:
    """Parse a condition or raise ValueError saying what is accepted."""
    bare = _BARE.match(text)
    if bare:
        return Condition(bare.group(2), "falsy" if bare.group(1) else "truthy")
    match = _COMPARISON.match(text)
    if not match:
        raise ValueError(f"cannot parse condition {text!r} (use key == 'text', key < 3, key or not key)")
    key, operator, literal = match.groups()
    if len(literal) >= 2 and literal[0] == literal[-1] and literal[0] in "'\"":
        if operator not in ("==", "!="):
            raise ValueError(f"condition {text!r}: text can only be compared with == or !=")
        return Condition(key, operator, literal[1:-1])
    try:
        return Condition(key, operator, float(literal))
    except ValueError:
        raise ValueError(f"condition {text!r}: {literal!r} is neither a quoted text nor a number") from None


@dataclass(frozen=True)
class Rule:
    condition: Condition
    prompt: str | None
    user_prefix: str | None


@dataclass(frozen=True)
class SelectionRules:
    default: str
    conditional: tuple[Rule, ...] = ()

    def prompt_for(self, context: Mapping[str, object]) -> str:
        for rule in self.conditional:
            if rule.prompt is not None and rule.condition.holds(context):
                return rule.prompt
        return self.default

    def user_prefix_for(self, context: Mapping[str, object]) -> str | None:
        for rule in self.conditional:
            if rule.user_prefix is not None and rule.condition.holds(context):
                return rule.user_prefix
        return None
