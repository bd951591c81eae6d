"""`{{macro}}` expansion: recursive, depth-limited, with cycle detection and unknown-name errors.

This is the one expansion used by the agents at runtime and by the expand_prompt CLI, so both
produce identical text. Macro text is inserted with surrounding whitespace stripped.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

MAX_DEPTH = 10
# Far above any real system prompt (the shipped ones are a few KB); counts intermediate levels too.
MAX_EXPANSION_CHARS = 1_000_000
PLACEHOLDER = re.compile(r"\{\{\s*([A-Za-z_][A-Za-z0-9_]*)\s*\}\}")


class MacroError(Exception):
    """Expansion failed; `chain` is the path of names from the expanded text to the problem."""

    def __init__(self, message: str, chain: tuple[str, ...]) -> None:
        super().__init__(message)
        self.chain = chain


class UnknownMacroError(MacroError):
    pass


class MacroCycleError(MacroError):
    pass


class MacroDepthError(MacroError):
    pass


class MacroSizeError(MacroError):
    pass


@dataclass(frozen=True)
class Annotation:
    """Mark macro boundaries in the output (`expand_prompt --comment`); never used at runtime."""

    indent: int = 2  # spaces per nesting level before block markers

    def wrap(self, name: str, depth: int, body: str) -> str:
        if "\n" not in body:  # a word or a phrase inside a sentence: keep the sentence on one line
            return f"<!-- {name} -->{body}<!-- /{name} -->"
        pad = " " * (self.indent * (depth - 1))
        return f"{pad}<!-- begin macro: {name} -->\n{body}\n{pad}<!-- end macro: {name} -->"


def _chain_text(chain: tuple[str, ...]) -> str:
    return " -> ".join(chain)


def expand(
    text: str,
    macros: Mapping[str, str],
    *,
    origin: str = "",
    annotation: Annotation | None = None,
    max_depth: int = MAX_DEPTH,
) -> str:
    """`text` with every `{{name}}` replaced, recursively, by the (stripped) text of macro `name`.

    Raises UnknownMacroError, MacroCycleError (naming the cycle, e.g. "a -> b -> a"),
    MacroDepthError (more than `max_depth` nested levels) or MacroSizeError (the expansion would
    produce more than MAX_EXPANSION_CHARS); a placeholder never survives.
    """
    result = _Expansion(macros, annotation, max_depth).run(text, (origin,) if origin else ())
    # Braces next to a placeholder can join into a new one ("{" + "{x}" + "}"): refuse, never leak it.
    for match in PLACEHOLDER.finditer(result):
        if match.group(1) in macros:
            chain = (origin,) if origin else ()
            raise MacroError(
                f"expansion formed a new placeholder {match.group(0)} from adjacent braces", chain
            )
    return result


class _Expansion:
    """One `expand` call: the expansions done so far and the characters it may still produce.

    Ten nested macros each naming the next one ten times are a few hundred bytes of YAML and
    10^10 characters of prompt (or, with empty macros, 10^10 calls producing nothing). So each
    macro is expanded once per nesting level (a macro that expanded once has no cycle and no
    unknown name below it, whatever chain leads to it), and every character produced, literal
    text and inserted macro text alike, is counted against MAX_EXPANSION_CHARS.
    """

    def __init__(self, macros: Mapping[str, str], annotation: Annotation | None, max_depth: int) -> None:
        self.macros = macros
        self.annotation = annotation
        self.max_depth = max_depth
        self.done: dict[tuple[str, int], str] = {}
        self.budget = MAX_EXPANSION_CHARS

    def spend(self, chars: int, chain: tuple[str, ...]) -> None:
        self.budget -= chars
        if self.budget < 0:
            raise MacroSizeError(
                f"expansion produces more than {MAX_EXPANSION_CHARS} characters"
                + (f" (expanding {_chain_text(chain)})" if chain else ""),
                chain,
            )

    def run(self, text: str, chain: tuple[str, ...], depth: int = 1) -> str:
        self.spend(len(text), chain)

        def replace(match: re.Match[str]) -> str:
            body = self.macro(match.group(1), chain, depth)
            self.spend(len(body), chain)
            return body

        return PLACEHOLDER.sub(replace, text)

    def macro(self, name: str, chain: tuple[str, ...], depth: int) -> str:
        path = (*chain, name)
        if name in chain:
            cycle = path[chain.index(name) :]
            raise MacroCycleError(f"macro cycle: {_chain_text(cycle)}", path)
        if name not in self.macros:
            where = f" (referenced via {_chain_text(chain)})" if chain else ""
            raise UnknownMacroError(f"unknown macro {{{{{name}}}}}{where}", path)
        if depth > self.max_depth:
            raise MacroDepthError(
                f"macros nested deeper than {self.max_depth} levels: {_chain_text(path)}", path
            )
        done = self.done.get((name, depth))
        if done is not None:
            return done
        body = self.run(self.macros[name].strip(), path, depth + 1)
        if self.annotation is not None:
            body = self.annotation.wrap(name, depth, body)
        self.done[(name, depth)] = body
        return body


def references(text: str) -> list[str]:
    """The macro names `text` refers to directly, in order of first appearance."""
    return list(dict.fromkeys(PLACEHOLDER.findall(text)))
