"""`byc agent` / `oai_realtime_agent` / `oai_command_agent` / `gemini_live_agent` /
`gemini_command_agent` before anything starts: the config file, `--set`, the environment, `--check`,
and the errors (one message, exit code 2, no secret printed)."""

from __future__ import annotations

import io
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from agent_graph import FAKE_KEY

from by_your_command.agents.app_logging import RedactingFormatter, setup_logging
from by_your_command.cli import agent as agent_cli
from by_your_command.cli import byc

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


@pytest.fixture(autouse=True)
def clean_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in (
        "OPENAI_API_KEY",
        "GEMINI_API_KEY",
        "GOOGLE_API_KEY",
        "BYC_BRIDGE_URL",
        "BYC_BRIDGE_TOKEN",
        "MY_KEY",
    ):
        monkeypatch.delenv(name, raising=False)


def write(tmp_path: Path, data: Any, name: str = "agent.yaml") -> str:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return str(path)


def run_byc(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = byc.main(["agent", *argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def checked(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    code, out, err = run_byc(capsys, *argv, "--check")
    assert code == 0, err
    effective: dict[str, Any] = yaml.safe_load(out)
    return effective


# --- errors ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        ({"colour": "blue"}, "colour: unknown key"),
        ({"provider": {"modell": "x"}}, "provider.modell: unknown key"),
        ({"bridge": {"port": 9090}}, "bridge.port: unknown key"),
        ({"pause_timeout_s": "ten"}, "pause_timeout_s: must be a number"),
        ({"role": "talker"}, "role: must be one of"),
        ({"provider": {"model": 5}}, "provider.model: must be str, got int 5"),
        ({"provider": {"noise_reduction": "loud"}}, "provider.noise_reduction: must be one of"),
        (
            {"provider": {"type": "telepathy"}},
            "provider.type: must be one of ['gemini', 'gpt_live', 'offline', 'openai']",
        ),
        ({"provider": "gpt"}, "provider: must be a mapping"),
        ({"prompt_id": "no_such_prompt"}, "prompt_id: no prompt 'no_such_prompt'"),
        ({"bridge": {"url": "http://robot:9090"}}, "bridge.url: must be ws://host:port"),
        ("- a list\n", "the top level must be a mapping"),
        ("key: [unclosed\n", "cannot read"),
    ],
)
def test_config_errors_are_one_message_and_exit_2(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    content: Any,
    expected: str,
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", FAKE_KEY)
    code, out, err = run_byc(capsys, "--config", write(tmp_path, content))
    assert code == 2
    assert out == ""
    assert err.count("\n") == 1 and err.startswith("byc agent: ") and expected in err
    assert FAKE_KEY not in err


def test_every_problem_is_named_at_once(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = write(tmp_path, {"prompt_id": "nope", "provider": {"voice": 3}})
    code, _, err = run_byc(capsys, "--config", config)
    assert code == 2
    assert "prompt_id: no prompt 'nope'" in err and "provider.voice: must be str" in err
    assert "OPENAI_API_KEY is not set" in err


@pytest.mark.parametrize(
    ("content", "env_name"),
    [({}, "OPENAI_API_KEY"), ({"provider": {"api_key_env": "MY_KEY"}}, "MY_KEY")],
)
def test_a_missing_key_names_its_environment_variable(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    content: dict[str, Any],
    env_name: str,
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY" if env_name != "OPENAI_API_KEY" else "OTHER", FAKE_KEY)
    code, _, err = run_byc(capsys, "--config", write(tmp_path, content))
    assert code == 2
    assert f"{env_name} is not set" in err and "from the environment" in err
    assert FAKE_KEY not in err


@pytest.mark.parametrize(
    ("content", "where"),
    [
        ({"provider": {"api_key": FAKE_KEY}}, "provider.api_key"),
        ({"api_key": FAKE_KEY}, "api_key"),
        ({"bridge": {"token": FAKE_KEY}}, "bridge.token"),
        ({"bridge": {"url": f"ws://robot:9090/?token={FAKE_KEY}"}}, "bridge.url"),
        ({"bridge": {"url": f"ws://me:{FAKE_KEY}@robot:9090"}}, "bridge.url"),
        (
            {"provider": {"extra_headers": {"Authorization": f"Bearer {FAKE_KEY}"}}},
            "extra_headers.Authorization",
        ),
    ],
)
def test_secrets_in_the_file_are_refused_without_being_echoed(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    content: dict[str, Any],
    where: str,
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", "sk-another-key-in-env")
    code, out, err = run_byc(capsys, "--config", write(tmp_path, content))
    assert code == 2 and where in err and "environment" in err
    assert FAKE_KEY not in out + err


def test_a_secret_given_with_set_is_refused_too(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_byc(capsys, "--config", write(tmp_path, {}), "--set", f"provider.api_key={FAKE_KEY}")
    assert code == 2 and "provider.api_key" in err and FAKE_KEY not in err


def test_the_earlier_projects_api_key_option_is_refused(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", "sk-env-key-0000")
    code = agent_cli.main_realtime(["--api-key", FAKE_KEY])
    err = capsys.readouterr().err
    assert code == 2 and "OPENAI_API_KEY" in err and FAKE_KEY not in err


def test_a_missing_config_file_is_a_config_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_byc(capsys, "--config", str(tmp_path / "absent.yaml"))
    assert code == 2 and "absent.yaml" in err
    code, _, err = run_byc(capsys, "--config", "agent_nobody_wrote.yaml")
    assert code == 2 and "cannot find agent_nobody_wrote.yaml" in err


def test_the_process_exits_2_with_one_line_on_stderr(tmp_path: Path) -> None:
    """The real executable path: exit status and stream, not just main()'s return value."""
    config = write(tmp_path, {"colour": "blue"})
    result = subprocess.run(
        [sys.executable, "-m", "by_your_command.cli.byc", "agent", "--config", config],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "OPENAI_API_KEY": FAKE_KEY},
    )
    assert result.returncode == 2
    assert result.stdout == ""
    assert result.stderr.splitlines() == [result.stderr.strip()] and "colour: unknown key" in result.stderr
    assert FAKE_KEY not in result.stderr


# --- the effective config ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "role", "prompt", "context"),
    [
        ("agent_openai.yaml", "conversation", "conversational_assistant", "own"),
        ("agent_openai_command.yaml", "command", "command_extractor", "shared"),
        ("agent_openai_tool.yaml", "tools", "combined_tool_agent", "own"),
    ],
)
def test_the_shipped_configs_are_valid(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    name: str,
    role: str,
    prompt: str,
    context: str,
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", FAKE_KEY)
    effective = checked(capsys, "--config", name)
    assert (effective["role"], effective["prompt_id"], effective["context_source"]) == (role, prompt, context)
    assert effective["provider"]["type"] == "openai"
    assert effective["provider"]["api_key_env"] == "OPENAI_API_KEY (set)"


@pytest.mark.parametrize(
    ("name", "role", "prompt", "context", "detections"),
    [
        ("agent_gemini.yaml", "conversation", "conversational_assistant", "own", False),
        ("agent_gemini_command.yaml", "command", "gemini_command_extractor", "shared", True),
        ("agent_gemini_tool.yaml", "tools", "combined_tool_agent", "own", False),
    ],
)
def test_the_shipped_gemini_configs_are_valid(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    name: str,
    role: str,
    prompt: str,
    context: str,
    detections: bool,
) -> None:
    monkeypatch.setenv("GEMINI_API_KEY", FAKE_KEY)
    code, out, err = run_byc(capsys, "--config", name, "--check")
    assert code == 0, err
    assert FAKE_KEY not in out + err
    effective = yaml.safe_load(out)
    assert (effective["role"], effective["prompt_id"], effective["context_source"]) == (role, prompt, context)
    assert effective["detections"] is detections
    assert effective["provider"]["type"] == "gemini"
    assert effective["provider"]["api_key_env"] == "GEMINI_API_KEY (set)"


@pytest.mark.parametrize(
    ("environment", "used"),
    [
        ({"GEMINI_API_KEY": FAKE_KEY}, "GEMINI_API_KEY"),
        ({"GOOGLE_API_KEY": FAKE_KEY}, "GOOGLE_API_KEY"),
        (
            {"GOOGLE_API_KEY": FAKE_KEY, "GEMINI_API_KEY": "AIza-other-key-0000"},
            "GOOGLE_API_KEY",
        ),  # the SDK's order
        ({"GOOGLE_API_KEY": "  ", "GEMINI_API_KEY": FAKE_KEY}, "GEMINI_API_KEY"),  # blank = unset
    ],
)
def test_the_gemini_key_comes_from_google_api_key_else_gemini_api_key(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    environment: dict[str, str],
    used: str,
) -> None:
    for name, value in environment.items():
        monkeypatch.setenv(name, value)
    code, out, err = run_byc(capsys, "--config", "agent_gemini.yaml", "--check")
    assert code == 0, err
    assert yaml.safe_load(out)["provider"]["api_key_env"] == f"{used} (set)"
    assert FAKE_KEY not in out + err


def test_a_missing_gemini_key_names_both_variables_and_api_key_env_names_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    code, out, err = run_byc(capsys, "--config", "agent_gemini.yaml")
    assert code == 2 and out == ""
    assert "neither GOOGLE_API_KEY nor GEMINI_API_KEY is set" in err and "from the environment" in err

    monkeypatch.setenv("GEMINI_API_KEY", FAKE_KEY)  # api_key_env: only the named variable counts
    config = write(tmp_path, {"provider": {"type": "gemini", "api_key_env": "MY_KEY"}})
    code, _, err = run_byc(capsys, "--config", config)
    assert code == 2 and "MY_KEY is not set" in err and "GEMINI_API_KEY" not in err
    monkeypatch.setenv("MY_KEY", "AIza-my-key-0000")
    assert checked(capsys, "--config", config)["provider"]["api_key_env"] == "MY_KEY (set)"


def test_check_prints_the_effective_config_without_secrets(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", FAKE_KEY)
    monkeypatch.setenv("BYC_BRIDGE_TOKEN", "bridge-token-4a4a4a4a")
    code, out, _ = run_byc(capsys, "--config", "agent_openai.yaml", "--check")
    assert code == 0
    assert FAKE_KEY not in out and "bridge-token-4a4a4a4a" not in out
    effective = yaml.safe_load(out.split("\n", 1)[1])
    assert effective["bridge"] == {"url": "ws://127.0.0.1:9090", "token_env": "BYC_BRIDGE_TOKEN (set)"}
    assert effective["provider"]["model"] == "gpt-realtime-2.1"
    assert effective["pause_timeout_s"] == 2.0 and effective["echo_mode"] == "gate"
    assert "characters" in effective["instructions"]


def test_values_come_from_file_then_environment_then_set(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MY_KEY", FAKE_KEY)
    config = write(
        tmp_path,
        {"echo_mode": "aec", "provider": {"api_key_env": "MY_KEY"}, "bridge": {"url": "ws://robot:9090"}},
    )
    effective = checked(capsys, "--config", config)
    assert effective["bridge"]["url"] == "ws://robot:9090" and effective["echo_mode"] == "aec"
    assert effective["provider"]["api_key_env"] == "MY_KEY (set)"

    monkeypatch.setenv("BYC_BRIDGE_URL", "ws://10.0.0.7:9191")
    assert checked(capsys, "--config", config)["bridge"]["url"] == "ws://10.0.0.7:9191"

    effective = checked(
        capsys,
        "--config", config,
        "--set", "bridge.url=ws://127.0.0.1:7000",
        "--set", "provider.model=gpt-realtime-2.1-mini",
        "--set", "min_barge_in_ms=250",
        "--set", "topics.response_cmd=",
        "-p", "42",
        "--prompt-id", "command_extractor",
    )  # fmt: skip
    assert effective["bridge"]["url"] == "ws://127.0.0.1:7000"
    assert effective["provider"]["model"] == "gpt-realtime-2.1-mini"
    assert effective["min_barge_in_ms"] == 250 and effective["pause_timeout_s"] == 42.0
    assert effective["topics"]["response_cmd"] == "" and effective["prompt_id"] == "command_extractor"


def test_a_malformed_set_is_a_config_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_byc(capsys, "--config", write(tmp_path, {}), "--set", "pause_timeout_s")
    assert code == 2 and "expected key=value" in err
    code, _, err = run_byc(
        capsys, "--config", write(tmp_path, {"echo_mode": "aec"}), "--set", "echo_mode.x=1"
    )
    assert code == 2 and "echo_mode is not a mapping" in err


def test_the_earlier_executables_default_to_their_config_and_ignore_ros_args(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("OPENAI_API_KEY", FAKE_KEY)
    assert agent_cli.main_command(["--check", "--ros-args", "-r", "__node:=cmd", "--"]) == 0
    assert yaml.safe_load(capsys.readouterr().out)["role"] == "command"
    assert agent_cli.main_realtime(["--check", "-p", "5", "--prompt-id", "combined_tool_agent"]) == 0
    effective = yaml.safe_load(capsys.readouterr().out)
    assert (effective["role"], effective["pause_timeout_s"]) == ("conversation", 5.0)
    assert effective["prompt_id"] == "combined_tool_agent"


def test_the_gemini_executables_default_to_their_config_and_ignore_ros_args(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("GEMINI_API_KEY", FAKE_KEY)
    assert agent_cli.main_gemini(["--check", "--ros-args", "-r", "__node:=talk", "--"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("# ") and "agent_gemini.yaml: valid" in out.splitlines()[0]
    effective = yaml.safe_load(out)
    assert (effective["role"], effective["provider"]["type"]) == ("conversation", "gemini")
    assert agent_cli.main_gemini_command(["--check", "-p", "7", "--ros-args", "-p", "x:=1"]) == 0
    out = capsys.readouterr().out
    assert "agent_gemini_command.yaml: valid" in out.splitlines()[0]
    effective = yaml.safe_load(out)
    assert (effective["role"], effective["provider"]["type"], effective["pause_timeout_s"]) == (
        "command",
        "gemini",
        7.0,
    )


@pytest.mark.parametrize("name", ["gemini_live_agent", "gemini_command_agent"])
def test_the_gemini_executables_are_installed(name: str) -> None:
    """The console scripts colcon installs (setup.py EXECUTABLES) run and refuse a missing key."""
    executable = shutil.which(name)
    assert executable is not None, f"{name} is not on PATH: run scripts/bootstrap.sh"
    environment = {k: v for k, v in os.environ.items() if k not in ("GEMINI_API_KEY", "GOOGLE_API_KEY")}
    result = subprocess.run([executable], capture_output=True, text=True, timeout=60, env=environment)
    assert result.returncode == 2 and result.stdout == ""
    assert (
        result.stderr.startswith(f"{name}: ") and "neither GOOGLE_API_KEY nor GEMINI_API_KEY" in result.stderr
    )


# --- logging -----------------------------------------------------------------------------------


@pytest.fixture
def restore_logging() -> Any:
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    package_level = logging.getLogger("by_your_command").level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)
    logging.getLogger("by_your_command").setLevel(package_level)


@pytest.mark.usefixtures("restore_logging")
def test_logging_names_the_agent_and_redacts_secrets_everywhere() -> None:
    stream = io.StringIO()
    setup_logging("talker", verbose=True, secrets=[FAKE_KEY, "tok-123456"], stream=stream)
    log = logging.getLogger("by_your_command.agents.test")
    log.debug("header Authorization: Bearer %s", FAKE_KEY)
    try:
        raise RuntimeError(f"refused tok-123456 and {FAKE_KEY}")
    except RuntimeError:
        log.exception("failed")
    text = stream.getvalue()
    assert FAKE_KEY not in text and "tok-123456" not in text
    assert text.count("***") == 4
    assert all("[agent:talker]" in line for line in text.splitlines() if line[:2].isdigit())
    formatter = RedactingFormatter("%(message)s", ["abc"])  # too short to be a secret: left alone
    record = logging.LogRecord("x", logging.INFO, __file__, 1, "abc", None, None)
    assert formatter.format(record) == "abc"
