"""A graph as ROS 2 launch actions: what every launch file in launch/ returns.

Only launch files call this, on a full ROS install: `launch` and `launch_ros` are not on PyPI, so
they are imported when a launch description is built, never when this module is imported (the
graph package must import on a pip-only install). Launch arguments are the graph's options; the
graph is built once the arguments are known (an OpaqueFunction), from the same description
`byc up` uses. Any process that exits ends the launch, as `byc up` does.
"""

from __future__ import annotations

import importlib
import shutil
import tempfile
from pathlib import Path
from typing import Any

from by_your_command.graph.model import PACKAGE, Graph
from by_your_command.graph.options import parse_options
from by_your_command.graph.processes import agent_config, write_yaml
from by_your_command.graph.profiles import PROFILES, build_graph, launch_arguments


def launch_description(profile: str) -> Any:
    """The LaunchDescription of `profile`: one DeclareLaunchArgument per option, then the graph."""
    launch = importlib.import_module("launch")
    actions = importlib.import_module("launch.actions")
    declared = [
        actions.DeclareLaunchArgument(
            argument.name, default_value=argument.default, description=argument.description
        )
        for argument in launch_arguments(profile)
    ]

    def build(context: Any) -> list[Any]:
        return graph_actions(profile, context)

    return launch.LaunchDescription([*declared, actions.OpaqueFunction(function=build)])


def graph_from_context(profile: str, context: Any) -> Graph:
    values = {
        argument.name: context.launch_configurations[argument.name] for argument in launch_arguments(profile)
    }
    return build_graph(profile, parse_options(values, PROFILES[profile].defaults))


def graph_actions(profile: str, context: Any) -> list[Any]:
    """Node and ExecuteProcess actions of the graph, with the launch arguments' values."""
    actions = importlib.import_module("launch.actions")
    ros_actions = importlib.import_module("launch_ros.actions")
    substitutions = importlib.import_module("launch_ros.substitutions")
    graph = graph_from_context(profile, context)

    def stop_all(name: str) -> list[Any]:
        return [actions.Shutdown(reason=f"{name} exited")]

    nodes = [
        ros_actions.Node(
            package=PACKAGE,
            executable=node.executable,
            name=node.name,
            namespace=graph.namespace,
            parameters=[dict(node.parameters)],
            remappings=list(node.remappings),
            output="screen",
            on_exit=stop_all(node.name),
        )
        for node in graph.nodes
    ]
    if not graph.agents:
        return nodes
    # Agents are not ROS nodes: plain processes, each given its config with the graph's overrides,
    # written to a directory that goes when the launch shuts down.
    run_dir = Path(tempfile.mkdtemp(prefix=f"byc-launch-{profile}-"))
    handlers = importlib.import_module("launch.event_handlers")
    remove_run_dir = actions.RegisterEventHandler(
        handlers.OnShutdown(on_shutdown=lambda _event, _context: shutil.rmtree(run_dir, ignore_errors=True))
    )
    agents = []
    for agent in graph.agents:
        config_file = write_yaml(run_dir / f"{agent.name}.yaml", agent_config(agent))
        executable = substitutions.ExecutableInPackage(executable=agent.executable, package=PACKAGE)
        agents.append(
            actions.ExecuteProcess(
                cmd=[executable, *agent.arguments, "--config", str(config_file)],
                name=agent.name,
                output="screen",
                on_exit=stop_all(agent.name),
            )
        )
    return [remove_run_dir, *nodes, *agents]  # registered before anything can exit
