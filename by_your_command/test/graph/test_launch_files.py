"""Each launch file builds its LaunchDescription from the graph description.

`launch` and `launch_ros` are not on PyPI: minimal stand-ins record what the launch file creates,
and the recorded nodes and processes are compared with the graph `byc up` would start.
"""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import pytest
import yaml
from graph.graph_files import AGENT_CONFIGS

from by_your_command.graph.model import Graph
from by_your_command.graph.options import parse_options
from by_your_command.graph.processes import merged
from by_your_command.graph.profiles import PROFILES, Agents, build_graph, launch_arguments

LAUNCH_DIR = Path(__file__).resolve().parents[2] / "launch"
WAV = Path(__file__).resolve().parents[1] / "data" / "corpus" / "clean_en_us.wav"


class Recorded:
    """A stand-in launch class: keeps its constructor arguments."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args
        self.kwargs = kwargs


def _module(name: str, **attributes: Any) -> ModuleType:
    module = ModuleType(name)
    for attribute, value in attributes.items():
        setattr(module, attribute, value)
    return module


def _recorded(name: str) -> type:
    return type(name, (Recorded,), {})


@pytest.fixture
def launch_stand_ins(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    action_names = (
        "DeclareLaunchArgument",
        "OpaqueFunction",
        "ExecuteProcess",
        "Shutdown",
        "RegisterEventHandler",
    )
    actions = _module("launch.actions", **{n: _recorded(n) for n in action_names})
    handlers = _module("launch.event_handlers", OnShutdown=_recorded("OnShutdown"))
    description = _recorded("LaunchDescription")
    modules = {
        "launch": _module("launch", LaunchDescription=description, actions=actions, event_handlers=handlers),
        "launch.actions": actions,
        "launch.event_handlers": handlers,
        "launch_ros": _module("launch_ros"),
        "launch_ros.actions": _module("launch_ros.actions", Node=_recorded("Node")),
        "launch_ros.substitutions": _module(
            "launch_ros.substitutions", ExecutableInPackage=_recorded("ExecutableInPackage")
        ),
    }
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, name, module)
    yield


def load_launch_file(profile: str) -> ModuleType:
    path = LAUNCH_DIR / f"{profile}.launch.py"
    spec = importlib.util.spec_from_file_location(f"launch_file_{profile}", path)
    assert spec and spec.loader, path
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def launch(profile: str, arguments: dict[str, str]) -> tuple[list[Recorded], list[Recorded]]:
    """(declared arguments, actions of the graph) as `ros2 launch <file> name:=value...` would get."""
    description = load_launch_file(profile).generate_launch_description()
    assert type(description).__name__ == "LaunchDescription"
    entities = description.args[0]
    declared = [e for e in entities if type(e).__name__ == "DeclareLaunchArgument"]
    (opaque,) = [e for e in entities if type(e).__name__ == "OpaqueFunction"]
    unknown = set(arguments) - {d.args[0] for d in declared}
    assert not unknown, f"{profile}.launch.py does not declare {unknown}"
    values = {d.args[0]: d.kwargs["default_value"] for d in declared}
    context = SimpleNamespace(launch_configurations={**values, **arguments})
    return declared, opaque.kwargs["function"](context)


def expected_graph(profile: str, arguments: dict[str, str]) -> Graph:
    return build_graph(profile, parse_options(arguments, PROFILES[profile].defaults))


def assert_matches(profile: str, arguments: dict[str, str], actions: list[Recorded]) -> None:
    graph = expected_graph(profile, arguments)
    nodes = [a for a in actions if type(a).__name__ == "Node"]
    processes = [a for a in actions if type(a).__name__ == "ExecuteProcess"]
    handlers = [a for a in actions if type(a).__name__ == "RegisterEventHandler"]
    assert len(nodes) + len(processes) + len(handlers) == len(actions)
    assert len(handlers) == (1 if processes else 0)
    assert [n.kwargs["name"] for n in nodes] == [n.name for n in graph.nodes]
    for action, node in zip(nodes, graph.nodes, strict=True):
        assert action.kwargs["package"] == "by_your_command"
        assert action.kwargs["executable"] == node.executable
        assert action.kwargs["namespace"] == graph.namespace
        assert action.kwargs["parameters"] == [dict(node.parameters)]
        assert action.kwargs["remappings"] == list(node.remappings)
        (shutdown,) = action.kwargs["on_exit"]  # one process gone ends the launch, as in byc up
        assert type(shutdown).__name__ == "Shutdown"
    assert [p.kwargs["name"] for p in processes] == [a.name for a in graph.agents]
    for action, agent in zip(processes, graph.agents, strict=True):
        executable, *words, config = action.kwargs["cmd"]
        assert (executable.kwargs["executable"], executable.kwargs["package"]) == ("byc", "by_your_command")
        assert words == ["agent", "--config"]
        original = AGENT_CONFIGS[Path(agent.config_file).name]
        assert yaml.safe_load(Path(config).read_text()) == merged(original, agent.overrides)
    if processes:  # the agents' configs are removed when the launch shuts down
        (on_shutdown,) = handlers[0].args
        assert type(on_shutdown).__name__ == "OnShutdown"
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
    namespaces = {a.kwargs["namespace"] for a in actions if type(a).__name__ == "Node"}
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
    names = [a.kwargs["name"] for a in actions if type(a).__name__ != "RegisterEventHandler"]
    assert "file_audio_publisher" in names and "audio_capture" not in names
    assert "mic_recorder" in names and ("voice_recorder" in names) == (profile != "byc")
    assert {a.kwargs["namespace"] for a in actions if type(a).__name__ == "Node"} == {"/grunt1/agent"}


@pytest.mark.unit
def test_no_agents_argument_starts_only_the_nodes(launch_stand_ins: None, config_dir: Path) -> None:
    # agent configs are not even looked for: none exists where this test points
    _, actions = launch("oai_dual_agent", {"agents": "false", "agent_config_dir": "/nonexistent"})
    assert actions and all(type(a).__name__ == "Node" for a in actions)
