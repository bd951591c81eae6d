"""Hostile prompt files: prompts.yaml (and the commands.yaml it names) loaded and expanded.

Any file gives a PromptLibrary or a configuration error (ConfigError, PromptFileError, a missing
file), never another exception; expansion of what loaded gives text or a MacroError; and work is
bounded: macro bombs, YAML alias bombs, deep nesting and huge files are refused, not computed.
"""

from __future__ import annotations

import atexit
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import pytest
from fuzzing import ODD_TEXT, TALLY, fuzz_settings
from hypothesis import given
from hypothesis import strategies as st
from yaml_fuzz import PLAIN, alias_bomb, documents, sometimes_wrong

from by_your_command.commands.vocabulary import load_vocabulary
from by_your_command.config_files.locate import ConfigFileNotFound
from by_your_command.config_files.located_yaml import MAX_FILE_BYTES, ConfigError
from by_your_command.prompts import expansion
from by_your_command.prompts.expansion import MAX_EXPANSION_CHARS, MacroError, MacroSizeError, expand
from by_your_command.prompts.library import PromptFileError, load_prompt_library

pytestmark = [pytest.mark.unit, pytest.mark.timeout(600)]

WORKDIR = Path(tempfile.mkdtemp(prefix="byc_fuzz_prompts_"))
atexit.register(shutil.rmtree, WORKDIR, ignore_errors=True)
NAMES = ["robot_name", "rules", "a", "b", "c", "cmd_response", "arm_presets", "nope"]  # nope: undefined


def macro_text() -> st.SearchStrategy[str]:
    name = st.sampled_from(NAMES[:-1]) | st.sampled_from(NAMES)  # "nope" (undefined) now and then
    piece = name.map("{{{{{}}}}}".format) | ODD_TEXT | st.sampled_from(["{", "}", "{x}", "\n"])
    repeated = st.tuples(name, st.integers(1, 50)).map(lambda p: f"{{{{{p[0]}}}}}" * p[1])
    return st.lists(piece | repeated, min_size=1, max_size=8).map("".join)


PROMPT = st.fixed_dictionaries(
    {"system_prompt": sometimes_wrong(macro_text())},
    optional={
        "name": sometimes_wrong(ODD_TEXT),
        "description": sometimes_wrong(ODD_TEXT),
        "version": sometimes_wrong(st.integers(0, 9)),
        "tested_with": sometimes_wrong(st.lists(ODD_TEXT, max_size=3)),
        "parent": PLAIN,
    },
)
CONDITIONS = (
    st.sampled_from(
        ["agent_role == 'command'", "typed", "not typed", "x < 3", "x >= 1e400", "x < 'a'", "== 3", "a b", ""]
    )
    | ODD_TEXT
)
RULE = st.fixed_dictionaries(
    {"condition": sometimes_wrong(CONDITIONS)},
    optional={"prompt": sometimes_wrong(st.sampled_from(["p", "q", "missing"])), "user_prefix": PLAIN},
)
PLAIN_TEXT = st.text(st.characters(codec="utf-8", exclude_characters="{}"), min_size=1, max_size=20)
MACROS = st.fixed_dictionaries(
    {
        "robot_name": sometimes_wrong(PLAIN_TEXT),
        "rules": sometimes_wrong(PLAIN_TEXT.map(lambda t: t + "{{robot_name}}")),
    },
    optional={name: sometimes_wrong(macro_text()) for name in ("a", "b", "c", "cmd_response", "arm_presets")},
)
LIBRARY = st.fixed_dictionaries(
    {
        "macros": sometimes_wrong(MACROS),
        "prompts": sometimes_wrong(st.fixed_dictionaries({"p": PROMPT}, optional={"q": PROMPT})),
        "selection_rules": sometimes_wrong(
            st.fixed_dictionaries(
                {"default": sometimes_wrong(st.just("p"))},
                optional={"conditional": sometimes_wrong(st.lists(RULE, max_size=3))},
            )
        ),
    },
    optional={
        "user_prompt_prefixes": sometimes_wrong(
            st.dictionaries(
                st.sampled_from(["typed", "x"]),
                st.fixed_dictionaries(
                    {"prefix": sometimes_wrong(macro_text().map(lambda t: t + " {operator}"))}
                ),
                max_size=2,
            )
        ),
        "command_vocabulary": sometimes_wrong(
            st.sampled_from(["commands.yaml"] * 6 + ["missing.yaml", "/dev/zero", "..", "/proc/self/status"])
        ),
        "metadata": PLAIN,
    },
)
COMMAND = st.fixed_dictionaries(
    {},
    optional={
        "description": sometimes_wrong(ODD_TEXT),
        "modifier": sometimes_wrong(st.sampled_from(["none", "optional", "required"])),
        "modifier_kind": sometimes_wrong(st.sampled_from(["direction", "label"])),
        "wake": sometimes_wrong(st.booleans()),
    },
)
VOCABULARY = st.fixed_dictionaries(
    {
        "arm_presets": sometimes_wrong(
            st.dictionaries(st.sampled_from(["pan", "lookup", "arm_presets"]), COMMAND)
        ),
        "behaviors": sometimes_wrong(st.dictionaries(st.sampled_from(["stop", "pan", "follow"]), COMMAND)),
    },
    optional={
        "bearings": sometimes_wrong(
            st.dictionaries(
                st.sampled_from(["left", "right", "stop"]), sometimes_wrong(st.integers(-200, 200))
            )
        ),
        "angle_range": sometimes_wrong(st.lists(st.integers(-200, 200), min_size=2, max_size=2)),
    },
)


def write(name: str, content: str | bytes) -> Path:
    path = WORKDIR / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8", "surrogatepass"))
    return path


CONTEXTS = st.dictionaries(st.sampled_from(["agent_role", "typed", "x"]), PLAIN, max_size=3)


@fuzz_settings(short=120, long=3_000)
@given(documents(LIBRARY), documents(VOCABULARY), CONTEXTS)
def test_any_prompt_file_loads_or_is_a_config_error(
    prompts: str | bytes, commands: str | bytes, context: dict[str, Any]
) -> None:
    path = write("prompts.yaml", prompts)
    write("commands.yaml", commands)
    with TALLY.input("prompts.load_prompt_library"):
        try:
            library = load_prompt_library(path)
        except (ConfigError, PromptFileError, ConfigFileNotFound) as error:
            assert str(error)
            return
        for prompt_id in library.prompts:
            library.system_prompt(prompt_id)  # verified at load: must expand without an error
        assert library.select_prompt(context) in library.prompts
        for prefix_id in library.user_prefixes:
            try:
                library.user_prefix(prefix_id, context)
            except (KeyError, MacroError):
                pass  # a missing {variable}, or a macro problem in the prefix: both are reported


@fuzz_settings(short=150, long=5_000)
@given(st.dictionaries(st.sampled_from(NAMES), macro_text(), max_size=8), macro_text())
def test_any_macro_set_expands_or_is_a_macro_error(macros: dict[str, str], text: str) -> None:
    with TALLY.input("prompts.expand"):
        try:
            result = expand(text, macros)
        except MacroError as error:
            assert str(error)
            return
        assert len(result) <= MAX_EXPANSION_CHARS


# --- regressions found by the fuzzer -----------------------------------------------------------------


def bomb(levels: int, fanout: int, leaf: str) -> dict[str, str]:
    """m0 names m1 `fanout` times, m1 names m2 ... : fanout**levels copies of the last macro."""
    macros = {f"m{i}": f"{{{{m{i + 1}}}}}" * fanout for i in range(levels)}
    macros[f"m{levels}"] = leaf
    return macros


def test_a_macro_bomb_is_refused_not_expanded() -> None:
    """Ten macros naming the next one ten times are 10^10 characters from 300 bytes of YAML;
    seven of them (10^7 characters, still expandable when the test fails) make the point."""
    with pytest.raises(MacroSizeError, match=f"more than {MAX_EXPANSION_CHARS} characters"):
        expand("{{m0}}", bomb(6, 10, "x" * 10))
    assert len(expand("{{m0}}", bomb(3, 10, "x" * 10))) == 10_000  # a modest fan-out is fine


def test_each_macro_is_expanded_once_per_level(monkeypatch: pytest.MonkeyPatch) -> None:
    """Empty macros produce nothing to count: 20^9 expansions of them must not happen."""

    class CountingPattern:
        def __init__(self, pattern: re.Pattern[str]) -> None:
            self.pattern = pattern
            self.subs = 0

        def sub(self, replace: Any, text: str) -> str:
            self.subs += 1
            return self.pattern.sub(replace, text)

        def finditer(self, text: str) -> Any:
            return self.pattern.finditer(text)

    counting = CountingPattern(expansion.PLACEHOLDER)
    monkeypatch.setattr(expansion, "PLACEHOLDER", counting)
    assert expand("{{m0}}", bomb(4, 20, "")) == ""
    assert counting.subs <= 4 + 2  # each macro's text scanned once, not 20^4 times


def test_a_macro_bomb_in_a_prompt_file_is_a_load_error() -> None:
    lines = ["prompts: {p: {system_prompt: '{{m0}}'}}", "selection_rules: {default: p}", "macros:"]
    lines += [f"  {name}: '{text}'" for name, text in bomb(7, 10, "x").items()]
    path = write("bomb_prompts.yaml", "\n".join(lines) + "\n")
    with pytest.raises(PromptFileError, match="more than"):
        load_prompt_library(path)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("prompts: " + "[" * 5000 + "]" * 5000, "nested deeper than 64 levels"),
        ("prompts: " + "{a: " * 3000 + "1" + "}" * 3000, "nested deeper than 64 levels"),
        ("- " * 2000 + "x", "nested too deeply"),
        (b"prompts: \xff\xfe\n", "not UTF-8"),
        ("# " + "x" * MAX_FILE_BYTES, f"larger than {MAX_FILE_BYTES} bytes"),
    ],
    ids=["deep-list", "deep-map", "deep-block", "latin-1", "huge"],
)
def test_deep_undecodable_or_huge_files_are_config_errors(content: str | bytes, message: str) -> None:
    """These used to escape as RecursionError (after seconds of PyYAML scanning for flow nesting) or
    UnicodeDecodeError, or be read whole."""
    for name in ("prompts.yaml", "commands.yaml"):
        path = write(f"odd_{name}", content)
        loader = load_prompt_library if name == "prompts.yaml" else load_vocabulary
        with pytest.raises(ConfigError, match=message):
            loader(path)


def test_an_alias_bomb_in_a_prompt_file_costs_nothing() -> None:
    """Aliases are shared when loaded, and the loader never walks unused values: a clear error."""
    bomb_lines = "".join(f"  {line}\n" for line in alias_bomb(12, 10).splitlines())
    path = write(
        "alias_prompts.yaml",
        f"metadata:\n{bomb_lines}prompts: {{p: {{system_prompt: *b11}}}}\nselection_rules: {{default: p}}\n",
    )
    with pytest.raises(ConfigError, match="must be a string"):
        load_prompt_library(path)
