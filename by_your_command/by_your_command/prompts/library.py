"""prompts.yaml as a validated PromptLibrary: prompts, macros, user prefixes, selection rules.

File layout (every key checked; errors name file, key and line):

    command_vocabulary: commands.yaml   # optional; its macros are generated (arm_presets, ...)
    macros:               {name: text}
    prompts:              {id: {name, description, version, tested_with, system_prompt}}
    user_prompt_prefixes: {id: {description, prefix}}     # prefix may use {variable}s
    selection_rules:      {default: id, conditional: [{condition, prompt | user_prefix}]}
    metadata:             {...}                            # free-form, ignored
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from by_your_command.commands.describe import vocabulary_macros
from by_your_command.commands.vocabulary import load_vocabulary
from by_your_command.config_files.locate import find_config_file
from by_your_command.config_files.located_yaml import ConfigError, LocatedDict, Section, load_located_yaml
from by_your_command.prompts.expansion import Annotation, MacroError, expand
from by_your_command.prompts.selection import Rule, SelectionRules, parse_condition

PROMPTS_FILE = "prompts.yaml"
# `{name}` in a user prefix; other braces (JSON examples in macros) stay as they are.
_VARIABLE = re.compile(r"(?<!\{)\{([A-Za-z_]\w*)\}(?!\})")


@dataclass(frozen=True)
class Prompt:
    id: str
    name: str
    description: str
    system_prompt: str
    version: str = ""
    tested_with: tuple[str, ...] = ()
    line: int = 0


@dataclass(frozen=True)
class UserPrefix:
    id: str
    description: str
    prefix: str


@dataclass(frozen=True)
class PromptLibrary:
    source: str
    macros: dict[str, str]
    prompts: dict[str, Prompt]
    user_prefixes: dict[str, UserPrefix]
    selection: SelectionRules
    generated_macros: frozenset[str] = frozenset()  # from the command vocabulary
    lines: dict[str, int] = field(default_factory=dict)  # name -> line in the file

    # -- names --------------------------------------------------------------------------------
    def kind_of(self, name: str) -> str | None:
        if name in self.prompts:
            return "prompt"
        if name in self.macros:
            return "macro"
        return None

    # -- expansion (identical for agents and the CLI) -----------------------------------------
    def expand_name(self, name: str, annotation: Annotation | None = None) -> str:
        """The fully expanded text of a prompt's system_prompt or of a macro.

        Raises KeyError for an unknown name and MacroError for cycles, unknown macros, depth.
        """
        if name in self.prompts:
            text = self.prompts[name].system_prompt
        elif name in self.macros:
            text = self.macros[name]
        else:
            raise KeyError(name)
        return expand(text.strip(), self.macros, origin=name, annotation=annotation)

    def system_prompt(self, prompt_id: str) -> str:
        if prompt_id not in self.prompts:
            raise KeyError(f"no prompt {prompt_id!r} in {self.source} (have: {', '.join(self.prompts)})")
        return self.expand_name(prompt_id)

    def select_prompt(self, context: Mapping[str, object] | None = None) -> str:
        return self.selection.prompt_for(context or {})

    def user_prefix(self, prefix_id: str, variables: Mapping[str, object]) -> str:
        """A user prompt prefix with macros expanded and {variables} filled (missing ones = error)."""
        if prefix_id not in self.user_prefixes:
            raise KeyError(f"no user prompt prefix {prefix_id!r} in {self.source}")
        text = expand(self.user_prefixes[prefix_id].prefix, self.macros, origin=prefix_id)
        missing = [name for name in _VARIABLE.findall(text) if name not in variables]
        if missing:
            raise KeyError(f"user prompt prefix {prefix_id!r} needs variables: {', '.join(missing)}")
        return _VARIABLE.sub(lambda match: str(variables[match.group(1)]), text)

    def problems(self) -> list[str]:
        """Every expansion error in the file (cycles, unknown macros, depth), one line each."""
        found = []
        for name in [*self.prompts, *self.macros]:
            try:
                self.expand_name(name)
            except MacroError as error:
                found.append(f"{self.source}:{self.lines.get(name, 0)}: {name}: {error}")
        return found


def _prompt(prompt_id: str, section: Section) -> Prompt:
    section.check_keys(
        {"name", "description", "version", "tested_with", "parent", "system_prompt"}, {"system_prompt"}
    )
    version = section.data.get("version", "")
    if not isinstance(version, (str, int, float)) or isinstance(version, bool):
        raise section.error("version", "must be a string or number")
    text = section.string("system_prompt")
    if not text.strip():
        raise section.error("system_prompt", "is empty")
    return Prompt(
        prompt_id,
        section.string("name", prompt_id),
        section.string("description", ""),
        text,
        str(version),
        tuple(section.string_list("tested_with")),
        section.data.line,
    )


def _selection(
    section: Section, prompts: Mapping[str, Prompt], prefixes: Mapping[str, UserPrefix]
) -> SelectionRules:
    section.check_keys({"default", "conditional"}, {"default"})
    default = section.string("default")
    if default not in prompts:
        raise section.error("default", f"names no prompt: {default!r}")
    raw_rules = section.data.get("conditional", [])
    if not isinstance(raw_rules, list):
        raise section.error("conditional", "must be a list of {condition, prompt | user_prefix}")
    rules = []
    for index, item in enumerate(raw_rules):
        if not isinstance(item, LocatedDict):
            raise section.error("conditional", f"item {index} must be a mapping")
        rule = Section(section.file, f"{section.key_path('conditional')}[{index}]", item)
        rule.check_keys({"condition", "prompt", "user_prefix"}, {"condition"})
        try:
            condition = parse_condition(rule.string("condition"))
        except ValueError as error:
            raise rule.error("condition", str(error)) from None
        prompt = rule.string("prompt") if "prompt" in item else None
        prefix = rule.string("user_prefix") if "user_prefix" in item else None
        if prompt is None and prefix is None:
            raise rule.error("", "a rule needs a prompt or a user_prefix")
        if prompt is not None and prompt not in prompts:
            raise rule.error("prompt", f"names no prompt: {prompt!r}")
        if prefix is not None and prefix not in prefixes:
            raise rule.error("user_prefix", f"names no user prompt prefix: {prefix!r}")
        rules.append(Rule(condition, prompt, prefix))
    return SelectionRules(default, tuple(rules))


def parse_library(root: Section, base_dir: Path) -> PromptLibrary:
    root.check_keys(
        {"command_vocabulary", "macros", "prompts", "user_prompt_prefixes", "selection_rules", "metadata"},
        {"prompts", "selection_rules"},
    )
    lines: dict[str, int] = {}
    macros: dict[str, str] = {}
    generated: dict[str, str] = {}
    if "command_vocabulary" in root.data:
        vocabulary_path = base_dir / root.string("command_vocabulary")
        try:
            generated = vocabulary_macros(load_vocabulary(vocabulary_path))
        except FileNotFoundError as error:
            raise root.error("command_vocabulary", str(error)) from None
    macro_section = root.section("macros")
    for name in macro_section.data:
        if name in generated:
            raise macro_section.error(name, "is generated from command_vocabulary: change it there")
        macros[name] = macro_section.string(name)
        lines[name] = macro_section.data.line_of(name)
    macros.update(generated)

    prompts: dict[str, Prompt] = {}
    prompt_section = root.section("prompts", required=True)
    for prompt_id, section in prompt_section.sections():
        if prompt_id in macros:
            raise prompt_section.error(prompt_id, "a prompt and a macro share this name")
        prompts[prompt_id] = _prompt(prompt_id, section)
        lines[prompt_id] = prompt_section.data.line_of(prompt_id)
    if not prompts:
        raise root.error("prompts", "defines no prompt")

    prefixes: dict[str, UserPrefix] = {}
    for prefix_id, section in root.section("user_prompt_prefixes").sections():
        section.check_keys({"description", "prefix"}, {"prefix"})
        prefixes[prefix_id] = UserPrefix(
            prefix_id, section.string("description", ""), section.string("prefix")
        )

    selection = _selection(root.section("selection_rules", required=True), prompts, prefixes)
    return PromptLibrary(root.file, macros, prompts, prefixes, selection, frozenset(generated), lines)


def load_prompt_library(path: str | Path | None = None, verify: bool = True) -> PromptLibrary:
    """Load prompts.yaml (from `path`, or the installed one) and, by default, check every expansion.

    Raises ConfigFileNotFound, ConfigError (naming file, key and line) or, with verify, PromptFileError
    listing every macro problem: a broken prompt file stops an agent at startup, never mid-session.
    """
    resolved = find_config_file(PROMPTS_FILE, path)
    library = parse_library(Section(str(resolved), "", load_located_yaml(resolved)), resolved.parent)
    if verify:
        problems = library.problems()
        if problems:
            raise PromptFileError(problems)
    return library


class PromptFileError(ValueError):
    def __init__(self, problems: list[str]) -> None:
        super().__init__("prompt file has macro errors:\n  " + "\n  ".join(problems))
        self.problems = problems


__all__ = ["ConfigError", "Prompt", "PromptFileError", "PromptLibrary", "UserPrefix", "load_prompt_library"]
