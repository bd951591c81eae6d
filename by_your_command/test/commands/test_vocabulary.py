"""commands.yaml: the shipped vocabulary, its validation errors, and the macros made from it."""

from __future__ import annotations

from pathlib import Path

import pytest

from by_your_command.commands.describe import vocabulary_macros
from by_your_command.commands.vocabulary import Category, ConfigError, ModifierUse, load_vocabulary

ISSUE_ARM_PRESETS = ["bumper", "tenhut", "lookup", "lookout", "reach", "pan"]
ISSUE_BEHAVIORS = ["stop", "follow", "track", "sleep", "wake", "move", "turn"]
ISSUE_BEARINGS = "back-left full-left left leftish forward rightish right full-right back-right back".split()


@pytest.mark.unit
def test_shipped_vocabulary_matches_the_issue() -> None:
    vocabulary = load_vocabulary()
    assert [spec.name for spec in vocabulary.of(Category.ARM)] == ISSUE_ARM_PRESETS
    assert [spec.name for spec in vocabulary.of(Category.BEHAVIOR)] == ISSUE_BEHAVIORS
    assert list(vocabulary.bearings) == ISSUE_BEARINGS
    assert vocabulary.bearings["back-left"] == -120 and vocabulary.bearings["back"] == 180
    assert vocabulary.commands["pan"].modifier is ModifierUse.REQUIRED
    assert vocabulary.commands["sleep"].wake is False and vocabulary.commands["wake"].wake is True


@pytest.mark.unit
def test_generated_macros_list_every_command_and_bearing() -> None:
    vocabulary = load_vocabulary()
    macros = vocabulary_macros(vocabulary)
    for name in ISSUE_ARM_PRESETS:
        assert f"- {name}" in macros["arm_presets"]
    for name in ISSUE_BEHAVIORS:
        assert f"- {name}" in macros["motion_commands"]
    assert "- back-left: -120°" in macros["bearing_presets"]
    assert "pan@<bearing or angle>" in macros["arm_presets"]
    assert "base@modifier" in macros["compound_commands"]


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "commands.yaml"
    path.write_text(text)
    return path


@pytest.mark.unit
@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        ("arm_presets: {}\n", "commands.yaml:1: behaviors", "required key is missing"),
        (
            "arm_presets:\n  pan:\n    modifier: sometimes\nbehaviors: {}\n",
            "commands.yaml:3: arm_presets.pan.modifier",
            "must be one of none, optional, required",
        ),
        (
            "arm_presets: {}\nbehaviors:\n  stop:\n    colour: red\n",
            "commands.yaml:4: behaviors.stop.colour",
            "unknown key",
        ),
        (
            "arm_presets: {}\nbehaviors: {}\nbearings:\n  left: west\n",
            "commands.yaml:4: bearings.left",
            "must be a number",
        ),
        (
            "arm_presets: {}\nbehaviors: {}\nbearings:\n  left: 1\n  left: 2\n",
            "commands.yaml:5",
            "duplicate key 'left' (first on line 4)",
        ),
        ("arm_presets: [\n", "commands.yaml:2", "invalid YAML"),
        (
            "arm_presets: {}\nbehaviors: {}\nangle_range: [5, 1]\n",
            "commands.yaml:3: angle_range",
            "min < max",
        ),
    ],
)
def test_bad_vocabulary_errors_name_file_key_and_line(
    tmp_path: Path, text: str, where: str, message: str
) -> None:
    with pytest.raises(ConfigError) as caught:
        load_vocabulary(_write(tmp_path, text))
    assert where in str(caught.value)
    assert message in str(caught.value)


@pytest.mark.unit
def test_missing_vocabulary_file_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing.yaml"):
        load_vocabulary(tmp_path / "missing.yaml")
