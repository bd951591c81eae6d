"""`{{macro}}` expansion edge cases: nesting depth, cycles, unknown names, whitespace, properties."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from by_your_command.prompts.expansion import (
    MAX_DEPTH,
    PLACEHOLDER,
    Annotation,
    MacroCycleError,
    MacroDepthError,
    MacroError,
    UnknownMacroError,
    expand,
    references,
)


def chain(length: int) -> dict[str, str]:
    """m1 -> m2 -> ... -> m<length>, the last one plain text."""
    macros = {f"m{i}": f"<{i}>{{{{m{i + 1}}}}}" for i in range(1, length)}
    macros[f"m{length}"] = f"<{length}>"
    return macros


@pytest.mark.unit
def test_plain_text_and_whitespace_tolerant_placeholders() -> None:
    macros = {"name": "  Barney \n", "hello": "Hi {{ name }}!"}
    assert expand("{{hello}} / {{name}}", macros) == "Hi Barney! / Barney"
    assert expand("no macros {here}", macros) == "no macros {here}"


@pytest.mark.unit
def test_ten_levels_of_nesting_expand() -> None:
    text = expand("{{m1}}", chain(MAX_DEPTH))
    assert text == "".join(f"<{i}>" for i in range(1, MAX_DEPTH + 1))


@pytest.mark.unit
def test_eleven_levels_is_an_error_naming_the_path() -> None:
    with pytest.raises(MacroDepthError) as caught:
        expand("{{m1}}", chain(MAX_DEPTH + 1), origin="prompt")
    assert "deeper than 10 levels" in str(caught.value)
    assert caught.value.chain == ("prompt", *(f"m{i}" for i in range(1, MAX_DEPTH + 2)))


@pytest.mark.unit
@pytest.mark.parametrize(
    ("macros", "start", "cycle"),
    [
        ({"a": "x {{a}}"}, "a", "a -> a"),
        ({"a": "x {{b}}", "b": "y {{a}}"}, "a", "a -> b -> a"),
        ({"a": "{{b}}", "b": "{{c}}", "c": "{{d}}", "d": "{{b}}"}, "a", "b -> c -> d -> b"),
    ],
)
def test_cycles_are_errors_naming_the_cycle(macros: dict[str, str], start: str, cycle: str) -> None:
    with pytest.raises(MacroCycleError) as caught:
        expand(f"start {{{{{start}}}}}", macros, origin="my_prompt")
    assert str(caught.value) == f"macro cycle: {cycle}"


@pytest.mark.unit
def test_a_cycle_is_found_even_when_the_origin_is_a_macro() -> None:
    with pytest.raises(MacroCycleError, match="a -> b -> a"):
        expand("{{b}}", {"a": "{{b}}", "b": "{{a}}"}, origin="a")


@pytest.mark.unit
def test_the_same_macro_twice_side_by_side_is_not_a_cycle() -> None:
    assert expand("{{a}} {{a}}", {"a": "{{b}}-{{b}}", "b": "x"}) == "x-x x-x"


@pytest.mark.unit
def test_unknown_macro_is_an_error_with_its_path() -> None:
    with pytest.raises(UnknownMacroError) as caught:
        expand("{{a}}", {"a": "{{b}}", "b": "{{missing}}"}, origin="p")
    assert str(caught.value) == "unknown macro {{missing}} (referenced via p -> a -> b)"


@pytest.mark.unit
def test_annotation_marks_inline_and_block_macros() -> None:
    macros = {"name": "Rex", "block": "line one\nby {{name}}"}
    text = expand("I am {{name}}.\n{{block}}", macros, annotation=Annotation(indent=4))
    assert text == (
        "I am <!-- name -->Rex<!-- /name -->.\n"
        "<!-- begin macro: block -->\nline one\nby <!-- name -->Rex<!-- /name -->\n<!-- end macro: block -->"
    )


@pytest.mark.unit
def test_braces_joining_into_a_placeholder_are_refused() -> None:
    with pytest.raises(MacroError, match="adjacent braces"):
        expand("{{{a}}}", {"a": "{b}", "b": "B"})


@pytest.mark.unit
def test_references_lists_direct_names_once() -> None:
    assert references("{{a}} {{ b }} {{a}} {c}") == ["a", "b"]


_NAMES = [f"n{i}" for i in range(8)]


@st.composite
def acyclic_macros(draw: st.DrawFn) -> dict[str, str]:
    """Macro i may only reference macros j > i: no cycles, depth < len(_NAMES). Literal text has
    opening braces but never closing ones, so pieces can never spell a placeholder by accident."""
    macros = {}
    for index, name in enumerate(_NAMES):
        later = _NAMES[index + 1 :]
        parts = draw(
            st.lists(
                st.one_of(
                    st.text(alphabet="abc {\n", max_size=5), st.sampled_from(later).map("{{{{{}}}}}".format)
                )
                if later
                else st.text(alphabet="abc {\n", max_size=5),
                max_size=4,
            )
        )
        macros[name] = "".join(parts)
    return macros


@pytest.mark.unit
@settings(max_examples=200, deadline=None)
@given(acyclic_macros(), st.sampled_from(_NAMES))
def test_acyclic_macros_always_expand_without_leftover_placeholders(
    macros: dict[str, str], start: str
) -> None:
    try:
        text = expand(f"{{{{{start}}}}}", macros)
    except MacroError as error:  # only the "braces joined into a placeholder" case is allowed here
        assert "adjacent braces" in str(error)
        return
    assert not any(match.group(1) in macros for match in PLACEHOLDER.finditer(text))
    # annotations only add markers: removing them gives back the plain text's words
    annotated = expand(f"{{{{{start}}}}}", macros, annotation=Annotation())
    assert annotated.count("<!--") % 2 == 0


@pytest.mark.unit
@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.sampled_from(_NAMES), st.text(alphabet="{}n01234567 x", max_size=20), max_size=8))
def test_arbitrary_macros_expand_or_fail_with_a_macro_error(macros: dict[str, str]) -> None:
    for name in macros:
        try:
            text = expand(macros[name], macros, origin=name)
        except MacroError:
            continue
        assert not any(match.group(1) in macros for match in PLACEHOLDER.finditer(text))
