"""Prompt macros generated from the command vocabulary, so prompts never restate it by hand."""

from __future__ import annotations

from by_your_command.commands.vocabulary import Category, CommandSpec, ModifierKind, ModifierUse, Vocabulary


def _degrees(value: float) -> str:
    return f"{value:+g}°" if value else "0°"


def _usage(spec: CommandSpec) -> str:
    modifier = "<label>" if spec.modifier_kind is ModifierKind.LABEL else "<bearing or angle>"
    if spec.modifier is ModifierUse.REQUIRED:
        return f"{spec.name}@{modifier}"
    if spec.modifier is ModifierUse.OPTIONAL:
        return f"{spec.name} (or {spec.name}@{modifier})"
    return spec.name


def _command_lines(specs: list[CommandSpec]) -> str:
    return "\n".join(f"- {_usage(spec)}: {spec.description}" for spec in specs)


def vocabulary_macros(vocabulary: Vocabulary) -> dict[str, str]:
    """Macro name -> text for the prompt library."""
    bearings = "\n".join(f"- {name}: {_degrees(degrees)}" for name, degrees in vocabulary.bearings.items())
    examples = ["pan@left", "turn@-30", "follow@person", "lookup@rightish"]
    low, high = vocabulary.angle_min, vocabulary.angle_max
    all_commands = [*vocabulary.commands, *vocabulary.bearings]
    return {
        "arm_presets": "Arm presets (move the arm and camera):\n"
        + _command_lines(vocabulary.of(Category.ARM)),
        "motion_commands": "Behaviors:\n" + _command_lines(vocabulary.of(Category.BEHAVIOR)),
        "bearing_presets": (
            "Bearings (degrees, negative is to the robot's left):\n"
            + bearings
            + f"\nAny number of degrees from {low:g} to {high:g} may be used instead of a bearing name."
        ),
        "compound_commands": (
            "A command is `base` or `base@modifier`. The modifier is a bearing name or an angle in "
            "degrees, or a short label for commands that follow or track something.\n"
            f"Examples: {', '.join(examples)}.\n"
            "A bearing name on its own means pan@<bearing>. Several commands may be given, one per line."
        ),
        "command_words": ", ".join(all_commands),
    }
