"""`byc demo` as a user runs it: a process, the real graph, the offline agent, its output checked."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import wave
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from byc_testing import running_process, wait_for

from by_your_command.demo import bundled_speech

# A transcript line: "[   12.3 s] command    lookup -> arm_preset: accepted"
_LINE = re.compile(r"^\[\s*(\d+\.\d) s\] (\S+)\s+(.*)$")
_ACCEPTED = re.compile(r"^(\S+) -> (\S+): accepted$")
# What the bundled file says while awake, and where the command processor routes it.
EXPECTED_ROUTES = {"lookup": "arm_preset", "pan@left": "arm_preset", "stop": "behavior_command"}
SPOKEN_WHILE_ASLEEP = ("turn@right", "turn right")
_LISTENING = re.compile(r"listening on ws://(127\.0\.0\.1:\d+)/")
RUN_TIMEOUT_S = 150  # the demo's own deadline is the file (27 s) + 60 s; this only stops a hang


@dataclass
class DemoRun:
    status: int
    out: str
    err: str
    out_dir: Path

    def events(self) -> list[tuple[str, str]]:
        return [(m[2], m[3]) for line in self.out.splitlines() if (m := _LINE.match(line))]

    def accepted(self) -> dict[str, str]:
        return {
            m[1]: m[2]
            for kind, detail in self.events()
            if kind == "command" and (m := _ACCEPTED.match(detail))
        }

    def explain(self) -> str:
        return f"exit {self.status}\n--- stdout\n{self.out}\n--- stderr\n{self.err}"


def run_demo(*args: str, env: dict[str, str] | None = None, out_dir: Path) -> DemoRun:
    argv = [sys.executable, "-m", "by_your_command.cli.byc", "demo", "--out", str(out_dir), *args]
    done = subprocess.run(
        argv, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, env=env or dict(os.environ)
    )
    return DemoRun(done.returncode, done.stdout, done.stderr, out_dir)


def audible_seconds(path: Path) -> float:
    """Seconds of 20 ms blocks louder than -40 dBFS (speech, not silence or a noise floor)."""
    with wave.open(str(path), "rb") as wav:
        rate = wav.getframerate()
        pcm = np.frombuffer(wav.readframes(wav.getnframes()), dtype="<i2").astype(np.float64)
    block = rate // 50
    blocks = pcm[: len(pcm) // block * block].reshape(-1, block)
    rms = np.sqrt((blocks**2).mean(axis=1)) if len(blocks) else np.zeros(0)
    return float((rms > 32768 * 0.01).sum()) / 50


@pytest.mark.e2e
def test_offline_demo_routes_the_spoken_commands_and_ignores_the_one_said_asleep(
    ros_namespace: str, tmp_path: Path
) -> None:
    run = run_demo("--namespace", ros_namespace.strip("/"), out_dir=tmp_path)
    assert run.status == 0, run.explain()
    accepted = run.accepted()
    for command, topic in EXPECTED_ROUTES.items():
        assert accepted.get(command) == topic, f"{command} not routed to {topic}\n{run.explain()}"
    commands = [detail for kind, detail in run.events() if kind == "command"]
    assert not [c for c in commands if any(word in c for word in SPOKEN_WHILE_ASLEEP)], run.explain()
    # The robot fell asleep and woke again, and nothing was routed in between.
    attention = [detail for kind, detail in run.events() if kind == "attention"]
    assert "asleep" in attention and "awake" in attention[attention.index("asleep") :], run.explain()
    asleep = False
    for kind, detail in run.events():
        if kind == "attention":
            asleep = detail == "asleep"
        elif kind == "command" and asleep and not detail.startswith("sleep ->"):
            # (the verdict of `sleep` itself may arrive after the state it caused: no order across topics)
            assert not _ACCEPTED.match(detail), f"routed while asleep: {detail}\n{run.explain()}"
    # The robot answered out loud: more speech than a few short acknowledgements.
    heard = [detail for kind, detail in run.events() if kind == "heard"]
    # The last "stop" is the safety stop's: its utterance is not a request when the stop names it
    # before the agent commits it (two topics, no order), so the agent hears 4 or 5.
    assert len(heard) >= 4, run.explain()
    assert any(kind == "latency" for kind, _ in run.events()), run.explain()
    reply_wav = tmp_path / "robot_said.wav"
    assert audible_seconds(reply_wav) > 2.5, run.explain()
    assert f"robot's voice     {reply_wav}" in run.out
    assert re.search(r"commands routed\s+[3-9]", run.out), run.explain()
    assert "done: the speech file was played and every reply finished" in run.out


# The cloud path, served by the OpenAI Realtime emulator (scripted replies, no spending): one scripted
# turn per utterance the agent receives, each with what it "heard".
EMULATOR_SCRIPT = {
    "pace": 1.0,
    "default_reply": {"say": "I did not catch that."},
    "turns": [
        {
            "heard": "look up",
            "tool": {"name": "robot_command", "arguments": {"command": "lookup"}},
            "then": {"say": "Looking up."},
        },  # fmt: skip
        {
            "heard": "pan left",
            "tool": {"name": "robot_command", "arguments": {"command": "pan@left"}},
            "then": {"say": "Panning left."},
        },  # fmt: skip
        {"heard": "what time is it", "say": "It is half past eleven."},
        {
            "heard": "go to sleep",
            "tool": {"name": "robot_command", "arguments": {"command": "sleep"}},
            "then": {"say": "Good night."},
        },  # fmt: skip
        # "turn right" is said asleep and never reaches the agent; "wake up" wakes the VAD itself
        {
            "heard": "stop",
            "tool": {"name": "robot_command", "arguments": {"command": "stop"}},
            "then": {"say": "Stopping."},
        },  # fmt: skip
    ],
}


def run_emulated_demo(
    emulator: str, script: dict[str, Any], provider: str, tmp_path: Path, namespace: str
) -> DemoRun:
    """`byc demo --provider provider` on the bundled speech, against `byc emulate emulator`
    speaking `script` (the demo's narration and results are the run's)."""
    script_file = tmp_path / "script.yaml"
    script_file.write_text(yaml.safe_dump(script))
    emulate = [sys.executable, "-m", "by_your_command.cli.byc", "emulate", emulator, "--port", "0"]
    with running_process([*emulate, "--script", str(script_file)]) as process:
        assert process.stdout is not None
        url = wait_for(lambda: _LISTENING.search(process.stdout.readline() if process.stdout else ""), 30)
        env = {**os.environ, "OPENAI_API_KEY": "sk-emulator", "OPENAI_BASE_URL": f"http://{url[1]}/v1"}
        # --input: the file, also where a microphone and a speaker exist
        args = ("--provider", provider, "--input", str(bundled_speech()), "--namespace", namespace.strip("/"))
        return run_demo(*args, env=env, out_dir=tmp_path / "out")


def assert_the_demo_was_followed(run: DemoRun, out_dir: Path) -> None:
    """The bundled speech's commands routed, its question answered, asleep and awake again, heard."""
    assert run.accepted() == {
        "lookup": "arm_preset",
        "pan@left": "arm_preset",
        "sleep": "behavior_command",
        "stop": "behavior_command",
    }, run.explain()
    events = run.events()
    assert ("heard", '"what time is it"') in events and ("robot", '"It is half past eleven."') in events
    attention = [detail for kind, detail in events if kind == "attention"]
    assert attention[attention.index("asleep") - 1 :][:3] == ["awake", "asleep", "awake"], run.explain()
    assert audible_seconds(out_dir / "robot_said.wav") > 2.0, run.explain()


@pytest.mark.e2e
def test_the_cloud_demo_narrates_the_graph_with_an_emulated_provider(
    ros_namespace: str, tmp_path: Path
) -> None:
    run = run_emulated_demo("openai", EMULATOR_SCRIPT, "openai", tmp_path, ros_namespace)
    assert run.status == 0, run.explain()
    assert "an OpenAI Realtime agent" in run.out  # no sound card here: the bundled file, a WAV
    # 5 turns, or 4 when the safety stop named its utterance before the agent committed it
    assert [kind for kind, _ in run.events()].count("latency") in (4, 5), run.explain()
    assert_the_demo_was_followed(run, tmp_path / "out")


# The same demo through the GPT-Live emulator: the model takes its turn when it hears the user stop
# (energy), and robot commands are client delegations, which the agent turns into robot_command
# calls with the words heard (the emulator's `heard`, here the commands themselves).
GPT_LIVE_SCRIPT = {
    "pace": 1.0,
    "default_reply": "I did not catch that.",
    "turns": [
        {"heard": "lookup", "delegate": True, "then": "Looking up."},
        {"heard": "pan@left", "delegate": True, "then": "Panning left."},
        {"heard": "what time is it", "say": "It is half past eleven."},
        {"heard": "sleep", "delegate": True, "then": "Good night."},
        # "turn right" is said asleep and never reaches the agent; "wake up" wakes the VAD itself
        {"heard": "stop", "delegate": True, "then": "Stopping."},
    ],
}


@pytest.mark.e2e
def test_the_gpt_live_demo_runs_full_duplex_behind_the_echo_canceller(
    ros_namespace: str, tmp_path: Path
) -> None:
    run = run_emulated_demo("gpt-live", GPT_LIVE_SCRIPT, "gpt-live", tmp_path, ros_namespace)
    assert run.status == 0, run.explain()
    assert "an OpenAI GPT-Live agent (full duplex)" in run.out
    assert re.search(r"profile gpt_live: .*echo_suppressor", run.out), run.explain()  # aec by default
    assert_the_demo_was_followed(run, tmp_path / "out")


@pytest.mark.e2e
def test_a_node_that_dies_fails_the_demo_and_is_named(ros_namespace: str, tmp_path: Path) -> None:
    broken = tmp_path / "broken.wav"
    broken.write_bytes(b"RIFF but not a wave file")
    run = run_demo("--namespace", ros_namespace.strip("/"), "--input", str(broken), out_dir=tmp_path)
    assert run.status == 1, run.explain()
    assert "FAILED: the graph failed: file_audio_publisher (exit status 1)" in run.err, run.explain()
    assert (tmp_path / "graph.log").read_text().count("[file_audio_publisher]") > 0


@pytest.mark.unit
@pytest.mark.parametrize(
    ("provider", "variables"),
    [
        ("openai", ("OPENAI_API_KEY",)),
        ("gemini", ("GEMINI_API_KEY", "GOOGLE_API_KEY")),
        ("gpt-live", ("OPENAI_API_KEY",)),
    ],
)
def test_a_cloud_demo_without_its_key_says_what_is_missing_and_exits_2(
    provider: str, variables: tuple[str, ...], tmp_path: Path
) -> None:
    env = {
        k: v for k, v in os.environ.items() if k not in ("OPENAI_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY")
    }
    run = run_demo("--provider", provider, env=env, out_dir=tmp_path)
    assert run.status == 2, run.explain()
    assert f"--provider {provider} needs an API key: set {' or '.join(variables)}" in run.err
    assert not list(tmp_path.iterdir()), "nothing may start without the key"


@pytest.mark.unit
def test_the_bundled_speech_ships_with_the_package() -> None:
    path = bundled_speech()
    with wave.open(str(path), "rb") as wav:
        assert (wav.getframerate(), wav.getnchannels(), wav.getsampwidth()) == (16000, 1, 2)
        seconds = wav.getnframes() / wav.getframerate()
    assert 20 <= seconds <= 30
    assert path.stat().st_size < 1_500_000
    assert path.parent.name == "demo" and (path.parent / "make_demo_speech.sh").is_file()
