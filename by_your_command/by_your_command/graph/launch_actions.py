"""A graph as ROS 2 launch actions: what every launch file in launch/ returns.

Only launch files call this, on a full ROS install: `launch` and `launch_ros` are not on PyPI, so
they are imported when a launch description is built, never when this module is imported (the
graph package must import on a pip-only install). Launch arguments are the graph's options; the
graph is built once the arguments are known (an OpaqueFunction), from the same description
`byc up` uses, and as strictly: a `name:=value` this file does not know stops the launch.

Any process that exits ends the launch, as `byc up` does; one that ended on its own, or stopped
uncleanly, raises from its on_exit handler: launch (3.4.3, LaunchService.run_async) logs the
exception, shuts everything down and returns 1, so `ros2 launch` exits 1 naming the process.
"""

from __future__ import annotations

import importlib
import itertools
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Any

from by_your_command.graph.model import PACKAGE, Graph
from by_your_command.graph.options import parse_options
from by_your_command.graph.processes import agent_config, write_yaml
from by_your_command.graph.profiles import PROFILES, build_graph, launch_arguments
from by_your_command.graph.supervisor import SupervisorConfig
from by_your_command.stop_signals import stopped_on_request

# Launch's own configurations, which `ros2 launch` accepts for any file (its --launch-prefix
# options add the first two to the command line).
LAUNCH_OWN_ARGUMENTS = frozenset(
    {"launch-prefix", "launch-prefix-filter", "sigterm_timeout", "sigkill_timeout", "emulate_tty"}
)


class ProcessEndedError(RuntimeError):
    """A launched process ended on its own, or did not stop cleanly: the launch must fail."""


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


def command_line_arguments(context: Any) -> dict[str, str] | None:
    """The `name:=value` words of the `ros2 launch` command line if it named this launch file,
    else None: a file that includes this one has arguments of its own, which are not ours."""
    launch_file = Path(getattr(context.locals, "current_launch_file_path", "") or "").name
    words_before_arguments = itertools.takewhile(lambda word: ":=" not in word, sys.argv[1:])
    if not launch_file or all(Path(word).name != launch_file for word in words_before_arguments):
        return None
    pairs = (word.split(":=", 1) for word in context.argv if ":=" in word)
    return {name: value for name, value in pairs if name not in LAUNCH_OWN_ARGUMENTS}


def graph_from_context(profile: str, context: Any) -> Graph:
    """The graph of the arguments' values, and of every other word on the command line, so that a
    misspelt option is refused (parse_options) and `node.param:=value` works as in `byc up --set`."""
    values = {
        argument.name: context.launch_configurations[argument.name] for argument in launch_arguments(profile)
    }
    values |= command_line_arguments(context) or {}
    return build_graph(profile, parse_options(values, PROFILES[profile].defaults))


def fail_unless_stopped(name: str) -> Any:
    """An on_exit handler: an exit while the launch runs, or an unclean one while it stops, fails it."""

    def on_exit(event: Any, context: Any) -> None:
        status = event.returncode
        if not context.is_shutdown:
            raise ProcessEndedError(f"FAILED: {name} exited with status {status} on its own; stopping all")
        if not stopped_on_request(status):
            raise ProcessEndedError(f"{name} stopped uncleanly (exit status {status})")

    return on_exit


def graph_actions(profile: str, context: Any) -> list[Any]:
    """Node and ExecuteProcess actions of the graph, with the launch arguments' values."""
    actions = importlib.import_module("launch.actions")
    ros_actions = importlib.import_module("launch_ros.actions")
    substitutions = importlib.import_module("launch_ros.substitutions")
    graph = graph_from_context(profile, context)
    # Launch's SIGTERM after SIGINT is a second signal: it must not cut a node's orderly stop,
    # which `byc up` gives this long too. `sigterm_timeout:=` still overrides it.
    sigterm_timeout = importlib.import_module("launch.substitutions").LaunchConfiguration(
        "sigterm_timeout", default=f"{SupervisorConfig.stop_timeout_s:g}"
    )
    nodes = [
        ros_actions.Node(
            package=PACKAGE,
            executable=node.executable,
            name=node.name,
            namespace=graph.namespace,
            parameters=[dict(node.parameters)],
            remappings=list(node.remappings),
            output="screen",
            on_exit=fail_unless_stopped(node.name),
            sigterm_timeout=sigterm_timeout,
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
                on_exit=fail_unless_stopped(agent.name),
                sigterm_timeout=sigterm_timeout,
            )
        )
    return [remove_run_dir, *nodes, *agents]  # registered before anything can exit
