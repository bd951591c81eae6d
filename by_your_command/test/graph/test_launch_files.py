"""Each launch file builds its LaunchDescription from the graph description, and behaves under the
stand-in for `ros2 launch` (launch_stand_in.py) as under `byc up`: a misspelt argument is refused,
a dying process fails the launch, Ctrl-C (twice delivered) stops every process in order.
"""

from __future__ import annotations

import os
import re
import signal
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import yaml
from graph.graph_files import AGENT_CONFIGS
from graph.launch_stand_in import Recorded, StandInLaunch, kind, stand_in_modules
from graph.up_runner import pid_alive, stand_in_launch, wait_for_exit, wait_vad_ready

from by_your_command.graph.model import Graph
from by_your_command.graph.options import parse_options
from by_your_command.graph.params import GraphError
from by_your_command.graph.processes import merged
from by_your_command.graph.profiles import PROFILES, Agents, build_graph, launch_arguments
from by_your_command.graph.supervisor import SupervisorConfig
from by_your_command.stop_signals import stopped_on_request

WAV = Path(__file__).resolve().parents[1] / "data" / "corpus" / "clean_en_us.wav"
VOICE_NODES = {"file_audio_publisher", "silero_vad_node", "voice_recorder"}
EXITED = re.compile(r"^\[launch\] process\[(\S+)\] exited with status (-?\d+)$")


@pytest.fixture
def launch_stand_ins(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    for name, module in stand_in_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    yield


def launch(profile: str, arguments: dict[str, str]) -> tuple[list[Recorded], list[Recorded]]:
    """(declared arguments, actions of the graph) as `ros2 launch <file> name:=value...` would get."""
    return StandInLaunch(profile, [f"{name}:={value}" for name, value in arguments.items()]).include()


def expected_graph(profile: str, arguments: dict[str, str]) -> Graph:
    return build_graph(profile, parse_options(arguments, PROFILES[profile].defaults))


def assert_matches(profile: str, arguments: dict[str, str], actions: list[Recorded]) -> None:
    graph = expected_graph(profile, arguments)
    nodes = [a for a in actions if kind(a) == "Node"]
    processes = [a for a in actions if kind(a) == "ExecuteProcess"]
    handlers = [a for a in actions if kind(a) == "RegisterEventHandler"]
    assert len(nodes) + len(processes) + len(handlers) == len(actions)
    assert len(handlers) == (1 if processes else 0)
    assert [n.kwargs["name"] for n in nodes] == [n.name for n in graph.nodes]
    for action, node in zip(nodes, graph.nodes, strict=True):
        assert action.kwargs["package"] == "by_your_command"
        assert action.kwargs["executable"] == node.executable
        assert action.kwargs["namespace"] == graph.namespace
        assert action.kwargs["parameters"] == [dict(node.parameters)]
        assert action.kwargs["remappings"] == list(node.remappings)
        assert callable(action.kwargs["on_exit"])  # one process gone ends the launch, as in byc up
    assert [p.kwargs["name"] for p in processes] == [a.name for a in graph.agents]
    for action, agent in zip(processes, graph.agents, strict=True):
        executable, *words, config = action.kwargs["cmd"]
        assert (executable.kwargs["executable"], executable.kwargs["package"]) == ("byc", "by_your_command")
        assert words == ["agent", "--config"]
        assert callable(action.kwargs["on_exit"])
        original = AGENT_CONFIGS[Path(agent.config_file).name]
        assert yaml.safe_load(Path(config).read_text()) == merged(original, agent.overrides)
    if processes:  # the agents' configs are removed when the launch shuts down
        (on_shutdown,) = handlers[0].args
        assert kind(on_shutdown) == "OnShutdown"
        on_shutdown.kwargs["on_shutdown"](None, None)
        assert not any(Path(p.kwargs["cmd"][-1]).parent.exists() for p in processes)


@pytest.mark.unit
@pytest.mark.parametrize("profile", list(PROFILES))
def test_launch_file_with_default_arguments(
    profile: str, launch_stand_ins: None, config_dir: Path, agent_dir: Path
) -> None:
    arguments = {} if PROFILES[profile].agents is Agents.NONE else {"agent_config_dir": str(agent_dir)}
    declared, actions = launch(profile, arguments)
    assert [(d.args[0], d.kwargs["default_value"]) for d in declared] == [
        (a.name, a.default) for a in launch_arguments(profile)
    ]
    assert_matches(profile, arguments, actions)
    namespaces = {a.kwargs["namespace"] for a in actions if kind(a) == "Node"}
    assert namespaces == {"/"}


@pytest.mark.unit
@pytest.mark.parametrize("profile", list(PROFILES))
def test_launch_file_arguments_change_the_graph(
    profile: str, launch_stand_ins: None, config_dir: Path, agent_dir: Path, tmp_path: Path
) -> None:
    arguments = {
        "namespace": "grunt1",
        "prefix": "agent",
        "audio_source": f"file:{WAV}",
        "echo_mode": "aec",
        "enable_voice_recorder": "false" if profile == "byc" else "true",
        "save_mic": "true",
        "recordings_dir": str(tmp_path),
    }
    if PROFILES[profile].agents is not Agents.NONE:
        arguments |= {
            "agent_config_dir": str(agent_dir),
            "audio_sink": f"wav:{tmp_path / 'reply.wav'}",
            "model": "model-x",
            "voice": "voice-y",
            "pause_timeout": "5",
        }
    _, actions = launch(profile, arguments)
    assert_matches(profile, arguments, actions)
    names = [a.kwargs["name"] for a in actions if kind(a) != "RegisterEventHandler"]
    assert "file_audio_publisher" in names and "audio_capture" not in names
    assert "mic_recorder" in names and ("voice_recorder" in names) == (profile != "byc")
    assert {a.kwargs["namespace"] for a in actions if kind(a) == "Node"} == {"/grunt1/agent"}


@pytest.mark.unit
def test_no_agents_argument_starts_only_the_nodes(launch_stand_ins: None, config_dir: Path) -> None:
    # agent configs are not even looked for: none exists where this test points
    _, actions = launch("oai_dual_agent", {"agents": "false", "agent_config_dir": "/nonexistent"})
    assert actions and all(kind(a) == "Node" for a in actions)


def node_action(actions: list[Recorded], name: str) -> Recorded:
    (action,) = [a for a in actions if kind(a) in ("Node", "ExecuteProcess") and a.kwargs["name"] == name]
    return action


@pytest.mark.unit
def test_a_misspelt_argument_is_refused(launch_stand_ins: None, config_dir: Path) -> None:
    """`byc up` refuses an unknown option; the launch file must not start in the root namespace."""
    with pytest.raises(GraphError, match="unknown option 'namesapce'"):
        StandInLaunch("byc", ["namesapce:=grunt1"]).include()


@pytest.mark.unit
def test_launch_own_arguments_and_node_parameters_are_taken(launch_stand_ins: None, config_dir: Path) -> None:
    words = ["launch-prefix:=xterm -e", "sigterm_timeout:=30", "silero_vad_node.threshold:=0.7"]
    stand_in = StandInLaunch("byc", words)
    _, actions = stand_in.include()
    vad = node_action(actions, "silero_vad_node")
    assert vad.kwargs["parameters"][0]["threshold"] == 0.7  # as `byc up --set silero_vad_node.threshold=0.7`
    assert stand_in.sigterm_timeout(vad) == 30


@pytest.mark.unit
def test_an_including_files_arguments_are_not_refused(launch_stand_ins: None, config_dir: Path) -> None:
    """Included from a user's launch file, the command line holds that file's arguments, not ours."""
    command = ["ros2", "launch", "my_robot", "robot.launch.py", "robot:=grunt"]
    _, actions = StandInLaunch("byc", ["robot:=grunt"], command=command).include()
    assert {a.kwargs["name"] for a in actions} >= {"audio_capture", "silero_vad_node"}


@pytest.mark.unit
def test_launch_gives_processes_as_long_to_stop_as_byc_up(launch_stand_ins: None, config_dir: Path) -> None:
    """Launch sends SIGTERM `sigterm_timeout` after its SIGINT: its default (5 s) cut the VAD's stop."""
    stand_in = StandInLaunch("byc", [])
    _, actions = stand_in.include()
    assert {stand_in.sigterm_timeout(a) for a in actions} == {SupervisorConfig.stop_timeout_s}


@pytest.mark.unit
def test_a_process_that_dies_fails_the_launch(
    launch_stand_ins: None, config_dir: Path, agent_dir: Path
) -> None:
    stand_in = StandInLaunch("offline", [f"agent_config_dir:={agent_dir}"])
    _, actions = stand_in.include()
    stand_in.process_exited(node_action(actions, "silero_vad_node"), -signal.SIGKILL)
    assert stand_in.return_code == 1  # `ros2 launch` exits 1, as `byc up` does
    assert stand_in.errors == [
        f"FAILED: silero_vad_node exited with status {-signal.SIGKILL} on its own; stopping all"
    ]
    assert stand_in.context.is_shutdown  # and the others are stopped
    config = Path(node_action(actions, "agent").kwargs["cmd"][-1])
    assert not config.parent.exists()  # the agents' run dir goes with the shutdown


@pytest.mark.unit
def test_stopping_on_request_keeps_status_0_unless_a_process_stops_uncleanly(
    launch_stand_ins: None, config_dir: Path
) -> None:
    stand_in = StandInLaunch("byc", [])
    _, actions = stand_in.include()
    stand_in.shutdown()  # Ctrl-C
    stand_in.process_exited(node_action(actions, "audio_capture"), 0)
    stand_in.process_exited(node_action(actions, "voice_recorder"), -signal.SIGINT)
    assert (stand_in.return_code, stand_in.errors) == (0, [])
    stand_in.process_exited(node_action(actions, "silero_vad_node"), 128 + signal.SIGINT)
    assert stand_in.return_code == 1
    assert stand_in.errors == [f"silero_vad_node stopped uncleanly (exit status {128 + signal.SIGINT})"]


@pytest.mark.ros
def test_ctrl_c_under_launch_stops_every_process_in_order(ros_namespace: str, tmp_path: Path) -> None:
    """The terminal's SIGINT reaches every process, then launch sends each its own: the copy must
    not be taken as a second Ctrl-C (it made every node skip its orderly stop)."""
    words = [
        f"namespace:={ros_namespace}",
        f"audio_source:=file:{WAV}",
        f"recordings_dir:={tmp_path}",
        "file_audio_publisher.rate_factor:=3.0",
    ]
    with stand_in_launch("byc", *words) as running:
        wait_vad_ready(running)
        children = running.children()
        assert set(children) == VOICE_NODES
        os.killpg(running.process.pid, signal.SIGINT)  # Ctrl-C: the terminal signals the whole group
        status = wait_for_exit(running)
        assert status == 0, running.output
        exits = dict(m.groups() for line in running.lines if (m := EXITED.match(line)))
        assert set(exits) == VOICE_NODES, running.output
        # 0, or killed by the copy once its stop was done (Python drops its handlers as it exits)
        assert all(stopped_on_request(int(status)) for status in exits.values()), running.output
        copies = [line for line in running.lines if line.startswith("[launch] sending signal 'SIGINT'")]
        assert copies, running.output  # the second SIGINT reached processes still stopping
        assert "exiting now" not in running.output
        assert not [name for name, pid in children.items() if pid_alive(pid)]
