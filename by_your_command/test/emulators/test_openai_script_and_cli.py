"""Script files for the emulator, and `byc emulate openai` as a process."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from openai import AsyncOpenAI

from by_your_command.emulators.openai_script import (
    CallTool,
    Say,
    ScriptError,
    Silence,
    Turn,
    load_script,
    script_from_mapping,
)

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

SCRIPT = """
pace: 0.5
session_expiry_s: 30
rejected_api_keys: [sk-bad]
turns:
  - heard: what do you see
    say: A red cup.
  - text: Only text here.
  - tool: {name: robot_command, arguments: {command: wave}}
    then: {say: I waved.}
  - silent: true
    heard: hmm
  - say: A long story.
    stall_after_ms: 300
    drop_after_ms: 500
"""


def test_a_yaml_script_loads_into_typed_turns(tmp_path: Path) -> None:
    path = tmp_path / "script.yaml"
    path.write_text(SCRIPT)
    script = load_script(path)
    assert script.pace == 0.5 and script.session_expiry_s == 30.0
    assert script.rejected_api_keys == ("sk-bad",)
    assert script.turns == (
        Turn(Say("A red cup."), heard="what do you see"),
        Turn(Say("Only text here.", "text")),
        Turn(CallTool("robot_command", '{"command": "wave"}', Say("I waved."))),
        Turn(Silence(), heard="hmm"),
        Turn(Say("A long story."), stall_after_ms=300, drop_after_ms=500),
    )


def test_the_documented_example_loads() -> None:
    import textwrap

    import by_your_command.emulators.openai_script as module

    assert module.__doc__ is not None
    example = textwrap.dedent(module.__doc__.split("every key optional):", 1)[1])
    script = script_from_mapping(yaml.safe_load(example))
    assert len(script.turns) == 6 and script.rejected_api_keys == ("sk-revoked",)


@pytest.mark.parametrize(
    ("text", "complaint"),
    [
        ("turns: [{say: hi, sing: la}]", "unknown key"),
        ("turns: [{say: hi, text: ho}]", "exactly one of"),
        ("turns: [{say: 5}]", "expected a string"),
        ("pace: fast", "expected a number"),
        ("pace: -1", "pace"),
        ("turns: [{say: hi, then: ok}]", "only follows a tool call"),
        ("volume: 11", "unknown key"),
        ("turns: [", "not valid YAML"),
    ],
)
def test_script_mistakes_are_named(tmp_path: Path, text: str, complaint: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ScriptError, match=complaint):
        load_script(path)


def test_byc_emulate_openai_serves_until_ctrl_c(tmp_path: Path) -> None:
    script = tmp_path / "script.yaml"
    script.write_text("turns: [{text: pong}]\n")
    command = [
        sys.executable,
        "-m",
        "by_your_command.cli.emulate",
        "openai",
        "--port",
        "0",
        "--script",
        str(script),
    ]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        first = process.stdout.readline()
        assert "ws://127.0.0.1:" in first, first + (
            process.stderr.read() if process.poll() is not None else ""
        )
        base_url = next(line for line in iter(process.stdout.readline, "") if "OPENAI_BASE_URL=" in line)
        base_url = base_url.split("OPENAI_BASE_URL=", 1)[1].strip()

        async def ping() -> str:
            client = AsyncOpenAI(api_key="sk-emulator", base_url=base_url)
            async with client.realtime.connect(model="gpt-realtime-2.1") as connection:
                await connection.response.create()
                async for event in connection:
                    if event.type == "response.output_text.done":
                        return event.text
            return ""

        assert asyncio.run(asyncio.wait_for(ping(), 20)) == "pong"
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=20) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def test_byc_emulate_reports_a_bad_script(tmp_path: Path) -> None:
    script = tmp_path / "script.yaml"
    script.write_text("turns: 5\n")
    result = subprocess.run(
        [sys.executable, "-m", "by_your_command.cli.emulate", "openai", "--script", str(script)],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ},
    )
    assert result.returncode == 2 and "script.turns" in result.stderr
