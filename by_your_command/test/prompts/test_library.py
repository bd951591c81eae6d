"""prompts.yaml loading: the shipped library, validation errors with lines, locating, selection."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from by_your_command.config_files.locate import ConfigFileNotFound, candidate_paths, find_config_file
from by_your_command.config_files.located_yaml import ConfigError
from by_your_command.prompts.library import PromptFileError, load_prompt_library

SHIPPED_PROMPTS = [
    "conversational_assistant",
    "command_extractor",
    "gemini_command_extractor",
    "combined_tool_agent",
    "visual_description",
]
VOCABULARY_MACROS = ["arm_presets", "bearing_presets", "motion_commands", "compound_commands"]


@pytest.mark.unit
def test_shipped_library_loads_and_every_prompt_expands() -> None:
    library = load_prompt_library()  # verify=True: any macro problem would raise here
    assert list(library.prompts) == SHIPPED_PROMPTS
    assert set(VOCABULARY_MACROS) <= library.generated_macros
    assert library.macros["robot_name"] == "Barney"
    for prompt_id in library.prompts:
        text = library.system_prompt(prompt_id)
        assert "{{" not in text and "Barney" in text


@pytest.mark.unit
def test_prompts_carry_the_vocabulary_from_commands_yaml() -> None:
    library = load_prompt_library()
    extractor = library.system_prompt("command_extractor")
    for word in (
        "bumper",
        "tenhut",
        "lookout",
        "pan@<bearing or angle>",
        "follow@<label>",
        "back-right: +120°",
    ):
        assert word in extractor
    assert "robot_command" in library.system_prompt("combined_tool_agent")
    assert "COMMAND: " in library.system_prompt("visual_description")


@pytest.mark.unit
def test_selection_rules_and_user_prefixes() -> None:
    library = load_prompt_library()
    assert library.select_prompt() == "conversational_assistant"
    assert library.select_prompt({"agent_role": "command"}) == "command_extractor"
    assert library.select_prompt({"agent_role": "tools"}) == "combined_tool_agent"
    assert library.select_prompt({"vision": True}) == "visual_description"
    assert library.selection.user_prefix_for({"typed": True}) == "typed_text"
    assert library.selection.user_prefix_for({}) is None
    assert library.user_prefix("typed_text", {"operator": "ann"}) == "[typed by ann] "
    with pytest.raises(KeyError, match="needs variables: operator"):
        library.user_prefix("typed_text", {})


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "prompts.yaml"
    path.write_text(text)
    return path


GOOD_TAIL = "selection_rules:\n  default: p\n"


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        (
            "prompts:\n  p:\n    system_prompt: hi\n",
            "prompts.yaml:1: selection_rules",
            "required key is missing",
        ),
        (
            "prompts:\n  p:\n    sytem_prompt: hi\n" + GOOD_TAIL,
            "prompts.yaml:3: prompts.p.sytem_prompt",
            "unknown key",
        ),
        (
            "prompts:\n  p:\n    system_prompt: [1]\n" + GOOD_TAIL,
            "prompts.yaml:3: prompts.p.system_prompt",
            "string",
        ),
        (
            "prompts:\n  p:\n    system_prompt: ''\n" + GOOD_TAIL,
            "prompts.yaml:3: prompts.p.system_prompt",
            "empty",
        ),
        (
            "prompts:\n  p:\n    system_prompt: a\nselection_rules:\n  default: q\n",
            "prompts.yaml:5",
            "names no prompt",
        ),
        (
            "macros:\n  p: x\nprompts:\n  p:\n    system_prompt: a\n" + GOOD_TAIL,
            "prompts.yaml:4: prompts.p",
            "a prompt and a macro share this name",
        ),
        (
            "prompts:\n  p:\n    system_prompt: a\n  p:\n    system_prompt: b\n" + GOOD_TAIL,
            "prompts.yaml:4",
            "duplicate key 'p' (first on line 2)",
        ),
        (
            "prompts:\n  p:\n    system_prompt: a\n"
            + GOOD_TAIL
            + "  conditional:\n    - condition: x ~ 3\n      prompt: p\n",
            "prompts.yaml:7: selection_rules.conditional[0].condition",
            "cannot parse condition",
        ),
        (
            "command_vocabulary: nowhere.yaml\nprompts:\n  p:\n    system_prompt: a\n" + GOOD_TAIL,
            "prompts.yaml:1: command_vocabulary",
            "cannot find",
        ),
        ("system_prompts:\n  p: {}\n", "prompts.yaml:1: system_prompts", "unknown key"),
    ],
)
def test_bad_files_name_file_key_and_line(tmp_path: Path, text: str, where: str, message: str) -> None:
    with pytest.raises(ConfigError) as caught:
        load_prompt_library(write(tmp_path, text))
    assert where in str(caught.value), str(caught.value)
    assert message in str(caught.value)


@pytest.mark.unit
def test_generated_macros_cannot_be_redefined_by_hand(tmp_path: Path) -> None:
    (tmp_path / "commands.yaml").write_text("arm_presets: {}\nbehaviors: {}\n")
    text = "command_vocabulary: commands.yaml\nmacros:\n  arm_presets: mine\n"
    text += "prompts:\n  p:\n    system_prompt: a\n"
    with pytest.raises(ConfigError, match=r"prompts.yaml:3: macros.arm_presets: is generated"):
        load_prompt_library(write(tmp_path, text + GOOD_TAIL))


@pytest.mark.unit
def test_macro_problems_stop_loading_with_every_problem_listed(tmp_path: Path) -> None:
    text = "macros:\n  a: '{{b}}'\n  b: '{{a}}'\nprompts:\n  p:\n    system_prompt: '{{nope}}'\n" + GOOD_TAIL
    with pytest.raises(PromptFileError) as caught:
        load_prompt_library(write(tmp_path, text))
    problems = caught.value.problems
    assert any(":5: p: unknown macro {{nope}}" in line for line in problems)
    assert any(":2: a: macro cycle: a -> b -> a" in line for line in problems)
    assert any(":3: b: macro cycle: b -> a -> b" in line for line in problems)
    # verify=False lets tools (expand_prompt) load it and report per name
    assert load_prompt_library(write(tmp_path, text), verify=False).kind_of("p") == "prompt"


@pytest.mark.unit
def test_locating_the_file_without_ament_index(tmp_path: Path) -> None:
    share = tmp_path / "prefix" / "share" / "by_your_command" / "config"
    share.mkdir(parents=True)
    (share / "prompts.yaml").write_text("x")
    environ = {"AMENT_PREFIX_PATH": os.pathsep.join([str(tmp_path / "empty"), str(tmp_path / "prefix")])}
    assert find_config_file("prompts.yaml", environ=environ) == share / "prompts.yaml"
    # with no prefix the package's own config directory (source checkout) is the last candidate
    assert candidate_paths("prompts.yaml", {})[-1].parts[-3:] == ("by_your_command", "config", "prompts.yaml")


@pytest.mark.unit
def test_a_missing_file_is_an_error_listing_where_it_looked(tmp_path: Path) -> None:
    with pytest.raises(ConfigFileNotFound) as caught:
        find_config_file("nothing_here.yaml", environ={"AMENT_PREFIX_PATH": str(tmp_path)})
    message = str(caught.value)
    assert "cannot find nothing_here.yaml" in message
    assert str(tmp_path / "share" / "by_your_command" / "config" / "nothing_here.yaml") in message
    with pytest.raises(ConfigFileNotFound, match="missing.yaml"):
        load_prompt_library(tmp_path / "missing.yaml")
