"""`{{macro}}` expansion: recursive, depth-limited, with cycle detection and unknown-name errors.

This is the one expansion used by the agents at runtime and by the expand_prompt CLI, so both
produce identical text. Macro text is inserted with surrounding whitespace stripped.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

MAX_DEPTH = 10
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

    Raises UnknownMacroError, MacroCycleError (naming the cycle, e.g. "a -> b -> a") or
    MacroDepthError (more than `max_depth` nested levels); a placeholder never survives.
    """
    result = _expand(text, macros, (origin,) if origin else (), 1, annotation, max_depth)
    # Braces next to a placeholder can join into a new one ("{" + "{x}" + "}"): refuse, never leak it.
    for match in PLACEHOLDER.finditer(result):
        if match.group(1) in macros:
            chain = (origin,) if origin else ()
            raise MacroError(
                f"expansion formed a new placeholder {match.group(0)} from adjacent braces", chain
            )
    return result


def _expand(
    text: str,
    macros: Mapping[str, str],
    chain: tuple[str, ...],
    depth: int,
    annotation: Annotation | None,
    max_depth: int,
) -> str:
    def replace(match: re.Match[str]) -> str:
        name = match.group(1)
        path = (*chain, name)
        if name in chain:
            cycle = path[chain.index(name) :]
            raise MacroCycleError(f"macro cycle: {_chain_text(cycle)}", path)
        if name not in macros:
            where = f" (referenced via {_chain_text(chain)})" if chain else ""
            raise UnknownMacroError(f"unknown macro {{{{{name}}}}}{where}", path)
        if depth > max_depth:
            raise MacroDepthError(f"macros nested deeper than {max_depth} levels: {_chain_text(path)}", path)
        body = _expand(macros[name].strip(), macros, path, depth + 1, annotation, max_depth)
        if annotation is None:
            return body
        return annotation.wrap(name, depth, body)

    return PLACEHOLDER.sub(replace, text)


def references(text: str) -> list[str]:
    """The macro names `text` refers to directly, in order of first appearance."""
    return list(dict.fromkeys(PLACEHOLDER.findall(text)))
