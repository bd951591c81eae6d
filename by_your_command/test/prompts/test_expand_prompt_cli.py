"""expand_prompt / `byc prompt`: golden outputs, exit codes, and identity with the runtime text.

Golden files live in test/prompts/golden/. After an intended change, regenerate them with
    BYC_UPDATE_GOLDEN=1 scripts/run_tests.sh by_your_command/test/prompts -q
and review the diff before committing.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from byc_testing import INSTALL_LIB

from by_your_command.cli import byc, expand_prompt
from by_your_command.prompts.library import load_prompt_library

HERE = Path(__file__).resolve().parent
GOLDEN = HERE / "golden"
FIXTURE = HERE / "data" / "fixture_prompts.yaml"
UPDATE = os.environ.get("BYC_UPDATE_GOLDEN") == "1"

# golden file -> arguments (the fixture file is used unless the case says otherwise)
CASES = {
    "fixture_list.txt": ["--list"],
    "fixture_helper.txt": ["helper"],
    "fixture_helper_comment.txt": ["helper", "--comment"],
    "fixture_helper_comment_indent4.txt": ["helper", "--comment", "--indent", "4"],
    "fixture_macro_safety.txt": ["safety"],
    "shipped_command_extractor.txt": ["command_extractor", "--shipped"],
    "shipped_visual_description.txt": ["visual_description", "--shipped"],
}


def run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = expand_prompt.main(args)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def case_args(args: list[str]) -> list[str]:
    if "--shipped" in args:
        return [arg for arg in args if arg != "--shipped"]
    return [*args, "--prompts-file", str(FIXTURE)]


@pytest.mark.unit
@pytest.mark.parametrize("golden", sorted(CASES))
def test_golden_outputs(golden: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(case_args(CASES[golden]), capsys)
    assert code == 0, err
    # the listing names the file it read: keep goldens free of machine paths
    out = "\n".join(line for line in out.splitlines() if not line.startswith("# ")) + "\n"
    path = GOLDEN / golden
    if UPDATE:
        path.write_text(out)
    assert path.is_file(), f"missing golden {path}: run with BYC_UPDATE_GOLDEN=1"
    assert out == path.read_text(), f"{golden} differs; regenerate with BYC_UPDATE_GOLDEN=1 if intended"


@pytest.mark.unit
@pytest.mark.parametrize(
    "prompt_id", ["conversational_assistant", "command_extractor", "combined_tool_agent"]
)
def test_cli_text_is_exactly_what_agents_get(prompt_id: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli([prompt_id], capsys)
    assert code == 0
    assert out == load_prompt_library().system_prompt(prompt_id) + "\n"


@pytest.mark.unit
@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        (["nope"], expand_prompt.EXIT_UNKNOWN_NAME, "unknown name 'nope': not a prompt or macro"),
        (
            ["broken_cycle_a"],
            expand_prompt.EXIT_MACRO_ERROR,
            "macro cycle: broken_cycle_a -> broken_cycle_b -> broken_cycle_a",
        ),
        (["broken_unknown"], expand_prompt.EXIT_MACRO_ERROR, "unknown macro {{not_defined}}"),
        ([], 2, "give a prompt or macro NAME, or --list"),
        (["helper", "--indent", "-1"], 2, "--indent must be >= 0"),
    ],
)
def test_errors_have_exit_codes_and_messages(
    args: list[str], code: int, message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    returned, out, err = run_cli([*args, "--prompts-file", str(FIXTURE)], capsys)
    assert returned == code
    assert out == ""
    assert message in err


@pytest.mark.unit
def test_missing_or_invalid_prompt_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_cli(["helper", "--prompts-file", str(tmp_path / "none.yaml")], capsys)
    assert code == expand_prompt.EXIT_BAD_FILE and "cannot find" in err
    bad = tmp_path / "bad.yaml"
    bad.write_text("prompts: [\n")
    code, _, err = run_cli(["helper", "--prompts-file", str(bad)], capsys)
    assert code == expand_prompt.EXIT_BAD_FILE and "bad.yaml:2" in err and "invalid YAML" in err


@pytest.mark.unit
def test_output_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "helper.txt"
    code, out, err = run_cli(["helper", "-o", str(target), "--prompts-file", str(FIXTURE)], capsys)
    assert code == 0 and out == "" and str(target) in err
    assert target.read_text() == (GOLDEN / "fixture_helper.txt").read_text()


@pytest.mark.unit
def test_byc_prompt_is_the_same_command(capsys: pytest.CaptureFixture[str]) -> None:
    assert byc.main(["prompt", "helper", "--comment", "--prompts-file", str(FIXTURE)]) == 0
    assert capsys.readouterr().out == (GOLDEN / "fixture_helper_comment.txt").read_text()


@pytest.mark.unit
def test_installed_executable_runs() -> None:
    executable = INSTALL_LIB / "expand_prompt"
    assert executable.is_file(), f"{executable} missing: run scripts/bootstrap.sh"
    result = subprocess.run(
        [str(executable), "helper", "--prompts-file", str(FIXTURE)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout == (GOLDEN / "fixture_helper.txt").read_text()
