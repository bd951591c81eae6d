"""`byc up`: starts a profile's processes, prefixes their logs, stops them all on Ctrl-C, and
exits non-zero naming a process that died."""

from __future__ import annotations

import os
import signal
import tempfile
from pathlib import Path

import pytest
from byc_testing import wait_for
from graph.up_runner import byc_up, pid_alive, wait_for_exit, wait_vad_ready

from by_your_command.cli import up

WAV = Path(__file__).resolve().parents[1] / "data" / "corpus" / "clean_en_us.wav"
VOICE_NODES = {"file_audio_publisher", "silero_vad_node", "voice_recorder"}


@pytest.fixture(autouse=True)
def run_dirs_in_tmp_path(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A dry run keeps its generated files (it prints commands that use them): here, in tmp_path."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))


def voice_only(namespace: str, recordings: Path) -> list[str]:
    return [
        "byc",
        "--namespace",
        namespace,
        "--set",
        f"audio_source=file:{WAV}",
        "--set",
        f"recordings_dir={recordings}",
        "--set",
        "file_audio_publisher.rate_factor=3.0",
    ]


@pytest.mark.ros
def test_up_runs_the_graph_and_stops_everything_on_ctrl_c(ros_namespace: str, tmp_path: Path) -> None:
    with byc_up(*voice_only(ros_namespace, tmp_path)) as running:
        wait_for(lambda: set(running.children()) == VOICE_NODES or running.check_running(), what="starts")
        # the graph works: an utterance went file -> VAD (gating on assistant_speaking) -> recorder
        wait_for(
            lambda: (
                any("wrote " in line for line in running.lines_of("voice_recorder"))
                or running.check_running()
            ),
            timeout=30,
            what="the recorder to log a written utterance",
        )
        assert list(tmp_path.glob("utterances/utterance_*.wav"))
        assert any("VAD ready" in line for line in running.lines_of("silero_vad_node")), running.output
        children = running.children()
        assert all(map(pid_alive, children.values()))
        status = running.stop(signal.SIGINT)
        assert status == 0, running.output
        assert not [name for name, pid in children.items() if pid_alive(pid)]
        for name in VOICE_NODES:
            assert f"{name} stopped" in running.output
        assert running.lines[-1].endswith("all processes stopped")


@pytest.mark.ros
def test_a_dying_node_stops_the_others_and_is_named(ros_namespace: str, tmp_path: Path) -> None:
    with byc_up(*voice_only(ros_namespace, tmp_path)) as running:
        wait_vad_ready(running)
        children = running.children()
        os.kill(children["silero_vad_node"], signal.SIGKILL)
        status = wait_for_exit(running)
        assert status == 1, running.output
        assert f"silero_vad_node exited with status {-signal.SIGKILL}" in running.output
        assert "FAILED: silero_vad_node" in running.lines[-1]
        assert not [name for name, pid in children.items() if pid_alive(pid)]


@pytest.mark.unit
def test_dry_run_prints_the_command_lines(capsys: pytest.CaptureFixture[str], config_dir: Path) -> None:
    status = up.main(
        ["byc", "--namespace", "robot1", "--set", "prefix=ears", "--set", "save_mic=true", "--dry-run"]
    )
    out = capsys.readouterr().out
    assert status == 0
    commands = [line for line in out.splitlines() if not line.startswith("#")]
    assert len(commands) == 4 and all("-r __ns:=/robot1/ears" in line for line in commands)
    assert "-r __node:=mic_recorder" in out and "-r response_voice:=audio" in out


@pytest.mark.unit
def test_missing_agent_config_is_reported_not_a_crash(
    capsys: pytest.CaptureFixture[str], config_dir: Path, tmp_path: Path
) -> None:
    status = up.main(["offline", "--set", f"agent_config_dir={tmp_path}", "--dry-run"])
    err = capsys.readouterr().err
    assert status == up.EXIT_BAD_GRAPH
    assert f"config file missing: no such file {tmp_path}/agent_offline.yaml" in err
    assert "byc up offline --no-agents" in err
    # and without agents the same profile starts
    assert up.main(["offline", "--set", f"agent_config_dir={tmp_path}", "--no-agents", "--dry-run"]) == 0
    assert "agent --config" not in capsys.readouterr().out


@pytest.mark.unit
def test_bad_option_exits_2_with_the_reason(capsys: pytest.CaptureFixture[str]) -> None:
    assert up.main(["byc", "--set", "echo_mode=loud", "--dry-run"]) == up.EXIT_BAD_GRAPH
    assert "echo_mode: one of gate, aec, external" in capsys.readouterr().err


@pytest.mark.unit
def test_byc_has_the_up_subcommand() -> None:
    from by_your_command.cli.byc import build_parser

    args = build_parser().parse_args(["up", "byc", "--dry-run"])
    assert args.run is up.run
