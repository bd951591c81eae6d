"""`byc emulate gemini` (cli/emulate_gemini.py) as a process: TLS, the printed settings work."""

from __future__ import annotations

import asyncio
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from by_your_command.agents.events import AssistantTranscript, ProviderEvent, ResponseDone
from by_your_command.agents.provider import SessionSetup
from by_your_command.agents.providers.gemini_live.provider import GeminiLiveConfig, GeminiLiveProvider

pytestmark = [pytest.mark.unit, pytest.mark.timeout(90)]


def test_byc_emulate_gemini_serves_tls_until_ctrl_c(tmp_path: Path) -> None:
    script = tmp_path / "script.yaml"
    script.write_text("turns: [{say: pong}]\n")
    command = [
        sys.executable,
        "-m",
        "by_your_command.cli.emulate_gemini",
        "--port",
        "0",
        "--script",
        str(script),
    ]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        first = process.stdout.readline()
        assert "wss://127.0.0.1:" in first, first + (
            process.stderr.read() if process.poll() is not None else ""
        )
        settings = re.search(r"base_url: (\S+)\s+ca_file: (\S+)", process.stdout.readline())
        assert settings is not None
        base_url, ca_file = settings.groups()
        assert Path(ca_file).is_file()

        async def ping() -> str:
            provider = GeminiLiveProvider(
                GeminiLiveConfig(base_url=base_url, ca_file=ca_file), api_key="emulator"
            )
            await provider.connect(SessionSetup("Answer."))
            try:
                await provider.send_text("ping")
                said: list[ProviderEvent] = []
                async for event in provider.events():
                    said.append(event)
                    if isinstance(event, ResponseDone):
                        break
                return "".join(e.text for e in said if isinstance(e, AssistantTranscript) and e.final)
            finally:
                await provider.close()

        assert asyncio.run(asyncio.wait_for(ping(), 30)) == "pong"
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=20) == 0
        assert not Path(ca_file).exists()  # the throwaway certificate is removed on stop
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def test_byc_emulate_gemini_reports_a_bad_script(tmp_path: Path) -> None:
    script = tmp_path / "script.yaml"
    script.write_text("turns: 5\n")
    result = subprocess.run(
        [sys.executable, "-m", "by_your_command.cli.emulate_gemini", "--script", str(script)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2 and "script.turns" in result.stderr
