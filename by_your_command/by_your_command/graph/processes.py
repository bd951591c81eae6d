"""A graph as processes to start: command lines, plus the files they read, written into a run dir.

Each node gets one generated params file keyed `/**` (any node, any namespace): the config files in
config/ are keyed by bare node names, which ROS applies only at the root namespace, and a generated
file also keeps every value's YAML type (`-p device:=1` would turn a device name into an int).
Each agent gets its config file with the graph's overrides merged in; the original is never edited.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from by_your_command.config_files.locate import find_config_file
from by_your_command.graph.model import PACKAGE, AgentSpec, Graph, NodeSpec
from by_your_command.graph.params import GraphError, Locate


@dataclass(frozen=True)
class ProcessSpec:
    name: str  # the node or agent name: `byc up` prefixes the process's output with it
    argv: tuple[str, ...]
    is_agent: bool = False


def find_executable(name: str, environ: Mapping[str, str] | None = None) -> str | None:
    """`name` on PATH (pip installs, scripts/env.sh), else where `ros2 run` looks: <prefix>/lib/<pkg>."""
    env = os.environ if environ is None else environ
    found = shutil.which(name, path=env.get("PATH"))
    if found:
        return found
    for prefix in filter(None, env.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        candidate = Path(prefix) / "lib" / PACKAGE / name
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return str(candidate)
    return None


def merged(base: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """`base` with `overrides` applied; nested mappings merge key by key."""
    result = dict(base)
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(result.get(key), Mapping):
            result[key] = merged(result[key], value)
        else:
            result[key] = value
    return result


def agent_config(agent: AgentSpec, locate: Locate = find_config_file) -> dict[str, Any]:
    """The agent's config file with the graph's overrides; GraphError names a missing file."""
    explicit = "/" in agent.config_file
    try:
        path = Path(agent.config_file) if explicit else locate(agent.config_file)
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except FileNotFoundError as error:
        where = f"no such file {agent.config_file}" if explicit else str(error)
        raise GraphError(f"agent {agent.name}: config file missing: {where}") from None
    except (OSError, yaml.YAMLError) as error:
        raise GraphError(f"agent {agent.name}: cannot read its config: {error}") from None
    if not isinstance(data, dict):
        raise GraphError(f"agent {agent.name}: {agent.config_file} is not a mapping")
    return merged(data, agent.overrides)


def write_yaml(path: Path, data: Mapping[str, Any]) -> Path:
    path.write_text(yaml.safe_dump(dict(data), sort_keys=False), encoding="utf-8")
    return path


def node_params_file(node: NodeSpec, run_dir: Path) -> Path:
    return write_yaml(
        run_dir / f"{node.name}.params.yaml", {"/**": {"ros__parameters": dict(node.parameters)}}
    )


def node_argv(node: NodeSpec, namespace: str, executable: str, params_file: Path) -> tuple[str, ...]:
    argv = [executable, "--ros-args", "-r", f"__node:={node.name}", "-r", f"__ns:={namespace}"]
    argv += ["--params-file", str(params_file)]
    for source, target in node.remappings:
        argv += ["-r", f"{source}:={target}"]
    return tuple(argv)


def prepare(
    graph: Graph,
    run_dir: Path,
    locate: Locate = find_config_file,
    which: Callable[[str], str | None] = find_executable,
) -> list[ProcessSpec]:
    """Write the files the processes read into `run_dir` and return their command lines.
    Checks everything first: one GraphError lists every missing executable and agent config."""
    problems: list[str] = []
    executables: dict[str, str] = {}
    for name in {*(n.executable for n in graph.nodes), *(a.executable for a in graph.agents)}:
        path = which(name)
        if path is None:
            problems.append(f"executable {name!r} not found on PATH nor in <prefix>/lib/{PACKAGE}")
        else:
            executables[name] = path
    configs: dict[str, dict[str, Any]] = {}
    for agent in graph.agents:
        try:
            configs[agent.name] = agent_config(agent, locate)
        except GraphError as error:
            problems.append(str(error))
    if problems:
        if graph.agents and any(p.startswith("agent ") for p in problems):
            problems.append(f"(to start the nodes without agents: byc up {graph.profile} --no-agents)")
        raise GraphError("cannot start the graph:\n  " + "\n  ".join(problems))
    processes = [
        ProcessSpec(
            node.name,
            node_argv(node, graph.namespace, executables[node.executable], node_params_file(node, run_dir)),
        )
        for node in graph.nodes
    ]
    for agent in graph.agents:
        config_file = write_yaml(run_dir / f"{agent.name}.yaml", configs[agent.name])
        argv = (executables[agent.executable], *agent.arguments, "--config", str(config_file))
        processes.append(ProcessSpec(agent.name, argv, is_agent=True))
    return processes
