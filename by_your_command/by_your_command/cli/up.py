"""`byc up <profile>`: start a profile's nodes and agents as processes (no `ros2 launch` needed).

The same graph description as the launch files (by_your_command.graph), so both start the same
nodes with the same parameters. Logs are prefixed with each process's name; Ctrl-C or SIGTERM
stops everything (exit 0 when all stopped cleanly); a process that ends on its own stops the rest,
and `byc up` exits 1 naming it. Exit 2: the graph cannot be built (a wrong option, a missing file).
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import sys
import tempfile
from pathlib import Path

from by_your_command.graph.options import parse_assignments, parse_options
from by_your_command.graph.params import GraphError
from by_your_command.graph.processes import ProcessSpec, prepare
from by_your_command.graph.profiles import PROFILES, build_graph, launch_arguments
from by_your_command.graph.supervisor import Supervisor, SupervisorConfig

EXIT_BAD_GRAPH = 2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    profiles = "; ".join(f"{p.name}: {p.description}" for p in PROFILES.values())
    parser.add_argument("profile", choices=list(PROFILES), help=f"the graph to start ({profiles})")
    parser.add_argument("--namespace", help="the robot's namespace (same as --set namespace=NS)")
    parser.add_argument(
        "--set",
        dest="assignments",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an option (byc up PROFILE --options lists them) or node.param=value; repeatable",
    )
    parser.add_argument("--no-agents", action="store_true", help="start the nodes only (agents elsewhere)")
    parser.add_argument(
        "--dry-run", action="store_true", help="print the command lines and files, start nothing"
    )
    parser.add_argument("--options", action="store_true", help="list the profile's options and defaults")
    parser.add_argument(
        "--stop-timeout",
        type=float,
        default=SupervisorConfig.stop_timeout_s,
        help="seconds between SIGTERM and SIGKILL when stopping (default %(default)s)",
    )


def _print_options(profile: str) -> None:
    for argument in launch_arguments(profile):
        print(f"{argument.name}={argument.default}\n    {argument.description}")


def _print_dry_run(processes: list[ProcessSpec], run_dir: Path) -> None:
    for process in processes:
        print(f"# {process.name}\n{shlex.join(process.argv)}")
    print(f"# generated params and agent configs are kept in {run_dir}")


def run(args: argparse.Namespace) -> int:
    if args.options:
        _print_options(args.profile)
        return 0
    try:
        values = parse_assignments(args.assignments)
        if args.namespace is not None:
            values["namespace"] = args.namespace
        if args.no_agents:
            values["agents"] = "false"
        options = parse_options(values, PROFILES[args.profile].defaults)
        graph = build_graph(args.profile, options)
    except GraphError as error:
        print(f"byc up: {error}", file=sys.stderr)
        return EXIT_BAD_GRAPH
    run_dir = Path(tempfile.mkdtemp(prefix=f"byc-up-{args.profile}-"))
    try:
        processes = prepare(graph, run_dir)
    except GraphError as error:
        shutil.rmtree(run_dir, ignore_errors=True)
        print(f"byc up: {error}", file=sys.stderr)
        return EXIT_BAD_GRAPH
    if args.dry_run:
        _print_dry_run(processes, run_dir)
        return 0
    try:
        supervisor = Supervisor(
            processes, sys.stdout, config=SupervisorConfig(stop_timeout_s=args.stop_timeout)
        )
        supervisor.say(f"profile {graph.profile} in namespace {graph.namespace}")
        return supervisor.run()
    finally:
        shutil.rmtree(run_dir, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="byc up", description="start a profile's nodes and agents")
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
