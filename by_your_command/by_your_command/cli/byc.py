"""`byc`: the project's command line (also `ros2 run by_your_command byc`).

Subcommands are registered in SUBCOMMANDS; each takes the parsed arguments and
returns a process exit code.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass

from by_your_command import __version__
from by_your_command.cli import agent, demo, emulate, expand_prompt, up


@dataclass(frozen=True)
class Check:
    name: str
    ok: bool
    detail: str
    required: bool = True


def _module_check(module: str, purpose: str, required: bool = True) -> Check:
    # find_spec, not import: doctor must not start rclpy or load models.
    found = importlib.util.find_spec(module) is not None
    return Check(module, found, purpose if found else f"missing ({purpose})", required)


def _program_check(program: str, purpose: str) -> Check:
    path = shutil.which(program)
    return Check(program, path is not None, path or f"missing ({purpose})")


def environment_checks() -> list[Check]:
    discovery = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "")
    return [
        Check("python", sys.version_info >= (3, 10), sys.version.split()[0]),
        _module_check("rclpy", "ROS 2 client library"),
        _module_check("by_your_command_msgs", "our messages, built by colcon (make bootstrap)"),
        _module_check("numpy", "audio arrays"),
        _module_check("yaml", "configuration files"),
        _program_check("espeak-ng", "offline speech synthesis"),
        _program_check("sox", "audio conversion"),
        Check(
            "ROS_AUTOMATIC_DISCOVERY_RANGE",
            discovery == "LOCALHOST",
            discovery or "unset: DDS discovery may leave this machine",
            required=False,
        ),
        Check("ROS_DOMAIN_ID", True, os.environ.get("ROS_DOMAIN_ID", "unset (0)"), required=False),
    ]


def cmd_doctor(_: argparse.Namespace) -> int:
    checks = environment_checks()
    width = max(len(check.name) for check in checks)
    for check in checks:
        mark = "ok  " if check.ok else ("FAIL" if check.required else "warn")
        print(f"{mark}  {check.name:<{width}}  {check.detail}")
    failed = [check.name for check in checks if check.required and not check.ok]
    if failed:
        print(f"\n{len(failed)} required check(s) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


@dataclass(frozen=True)
class Subcommand:
    help: str
    run: Callable[[argparse.Namespace], int]
    add_arguments: Callable[[argparse.ArgumentParser], None] | None = None


SUBCOMMANDS: dict[str, Subcommand] = {
    "doctor": Subcommand("check that this machine can run by_your_command", cmd_doctor),
    "demo": Subcommand(
        "run the voice demo through the real graph (offline by default) with a live transcript",
        demo.run,
        demo.add_arguments,
    ),
    "prompt": Subcommand(
        "list prompts and macros, or print one expanded exactly as agents get it",
        expand_prompt.run,
        expand_prompt.add_arguments,
    ),
    "up": Subcommand("start a profile's nodes and agents (no ros2 launch needed)", up.run, up.add_arguments),
    "emulate": Subcommand(
        "run a local OpenAI Realtime, GPT-Live or Gemini Live stand-in with scripted replies",
        emulate.run,
        emulate.add_arguments,
    ),
    "agent": Subcommand("run an agent process (an LLM talking to the robot)", agent.run, agent.add_arguments),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="byc", description="Talk to your robot: by_your_command tools.")
    parser.add_argument("--version", action="version", version=f"by_your_command {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, subcommand in SUBCOMMANDS.items():
        subparser = subparsers.add_parser(name, help=subcommand.help, description=subcommand.help)
        if subcommand.add_arguments is not None:
            subcommand.add_arguments(subparser)
        subparser.set_defaults(run=subcommand.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.run(args))


if __name__ == "__main__":
    sys.exit(main())
