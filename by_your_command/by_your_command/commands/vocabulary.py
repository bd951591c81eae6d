"""The command vocabulary (config/commands.yaml) as typed, validated data."""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass
from pathlib import Path

from by_your_command.config_files.locate import find_config_file
from by_your_command.config_files.located_yaml import ConfigError, Section, load_located_yaml

COMMANDS_FILE = "commands.yaml"
NAME_PATTERN = re.compile(r"^[a-z][a-z0-9_-]*$")


class Category(enum.Enum):
    ARM = "arm"
    BEHAVIOR = "behavior"


class ModifierUse(enum.Enum):
    NONE = "none"
    OPTIONAL = "optional"
    REQUIRED = "required"


class ModifierKind(enum.Enum):
    DIRECTION = "direction"  # a bearing name or a numeric angle in degrees
    LABEL = "label"  # a short free label: follow@person


@dataclass(frozen=True)
class CommandSpec:
    name: str
    category: Category
    description: str
    modifier: ModifierUse
    modifier_kind: ModifierKind
    wake: bool | None = None  # sleep/wake also drive wake_cmd


@dataclass(frozen=True)
class Vocabulary:
    commands: dict[str, CommandSpec]
    bearings: dict[str, float]  # name -> degrees, negative to the left
    angle_min: float = -180.0
    angle_max: float = 180.0

    def of(self, category: Category) -> list[CommandSpec]:
        return [spec for spec in self.commands.values() if spec.category is category]


_DEFAULT_MODIFIER = {Category.ARM: ModifierUse.OPTIONAL, Category.BEHAVIOR: ModifierUse.NONE}
_SECTIONS = {"arm_presets": Category.ARM, "behaviors": Category.BEHAVIOR}


def _enum_value(section: Section, key: str, enum_type: type[enum.Enum], default: enum.Enum) -> enum.Enum:
    raw = section.string(key, default.value)
    try:
        return enum_type(raw)
    except ValueError:
        choices = ", ".join(member.value for member in enum_type)
        raise section.error(key, f"must be one of {choices}, got {raw!r}") from None


def _command(name: str, category: Category, section: Section) -> CommandSpec:
    section.check_keys({"description", "modifier", "modifier_kind", "wake"})
    wake = section.data.get("wake")
    if wake is not None and not isinstance(wake, bool):
        raise section.error("wake", "must be true or false")
    modifier = _enum_value(section, "modifier", ModifierUse, _DEFAULT_MODIFIER[category])
    kind = _enum_value(section, "modifier_kind", ModifierKind, ModifierKind.DIRECTION)
    assert isinstance(modifier, ModifierUse) and isinstance(kind, ModifierKind)
    return CommandSpec(name, category, section.string("description", ""), modifier, kind, wake)


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def parse_vocabulary(root: Section) -> Vocabulary:
    root.check_keys({"angle_range", "arm_presets", "behaviors", "bearings"}, {"arm_presets", "behaviors"})
    commands: dict[str, CommandSpec] = {}
    for section_key, category in _SECTIONS.items():
        for name, section in root.section(section_key, required=True).sections():
            if not NAME_PATTERN.match(name):
                raise section.error("", "command names are lower-case words (a-z, 0-9, - and _)")
            if name in commands:
                raise section.error("", f"{name!r} is both an arm preset and a behavior")
            commands[name] = _command(name, category, section)
    bearings_section = root.section("bearings")
    bearings: dict[str, float] = {}
    for name, degrees in bearings_section.data.items():
        number = _number(degrees)
        if number is None:
            raise bearings_section.error(name, "a bearing must be a number of degrees")
        if not NAME_PATTERN.match(name) or name in commands:
            raise bearings_section.error(name, "bearing names are lower-case words distinct from commands")
        bearings[name] = number
    angle_range = root.data.get("angle_range", [-180, 180])
    bounds = [_number(item) for item in angle_range] if isinstance(angle_range, list) else []
    if len(bounds) != 2 or bounds[0] is None or bounds[1] is None or bounds[0] >= bounds[1]:
        raise root.error("angle_range", "must be [min, max] in degrees with min < max")
    vocabulary = Vocabulary(commands, bearings, bounds[0], bounds[1])
    for name, degrees in bearings.items():
        if not vocabulary.angle_min <= degrees <= vocabulary.angle_max:
            raise bearings_section.error(name, "bearing lies outside angle_range")
    return vocabulary


def load_vocabulary(path: str | Path | None = None) -> Vocabulary:
    """Load commands.yaml from `path`, or the one installed with the package."""
    resolved = find_config_file(COMMANDS_FILE, path)
    return parse_vocabulary(Section(str(resolved), "", load_located_yaml(resolved)))


__all__ = [
    "ConfigError",
    "Category",
    "CommandSpec",
    "ModifierKind",
    "ModifierUse",
    "Vocabulary",
    "load_vocabulary",
]
