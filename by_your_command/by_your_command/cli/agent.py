"""`byc agent --config FILE`: run one agent process (also `oai_realtime_agent`, `oai_command_agent`,
`gemini_live_agent`, `gemini_command_agent`).

    byc agent --config agent_openai.yaml                 # a file name is searched in config/
    byc agent -c my.yaml --set provider.model=gpt-realtime-2.1-mini --set echo_mode=external
    byc agent -c my.yaml --check                         # validate, print the effective config
    ros2 run by_your_command oai_realtime_agent -p 20    # the earlier project's names and options
    ros2 run by_your_command gemini_live_agent           # config/agent_gemini.yaml

The API key comes from OPENAI_API_KEY (Gemini: GOOGLE_API_KEY, else GEMINI_API_KEY; or the variable
named by provider.api_key_env), the bridge
from bridge.url or BYC_BRIDGE_URL, its token from BYC_BRIDGE_TOKEN (bridge.token_env). Exit codes:
0 stopped by Ctrl-C/SIGTERM, 1 fatal error (refused key or token), 2 configuration error.
"""

from __future__ import annotations

import argparse
import os
import sys

import yaml

from by_your_command.agents.app import EXIT_CONFIG, prepare, run_agent_process
from by_your_command.agents.app_config import describe, load_app_config
from by_your_command.agents.app_logging import setup_logging
from by_your_command.agents.config import AgentConfigError

REALTIME_CONFIG = "agent_openai.yaml"
COMMAND_CONFIG = "agent_openai_command.yaml"
GEMINI_CONFIG = "agent_gemini.yaml"
GEMINI_COMMAND_CONFIG = "agent_gemini_command.yaml"


def add_arguments(parser: argparse.ArgumentParser, default_config: str | None = None) -> None:
    parser.add_argument(
        "--config",
        "-c",
        required=default_config is None,
        default=default_config,
        help="agent config YAML: a path, or a file name searched in the config directories"
        + (f" (default: {default_config})" if default_config else ""),
    )
    parser.add_argument(
        "--set",
        dest="assignments",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config value (nested keys with dots, values in YAML); repeatable",
    )
    parser.add_argument("--check", action="store_true", help="validate, print the effective config, exit")
    parser.add_argument("--verbose", "-v", action="store_true", help="debug logging for this package")
    parser.add_argument(
        "--pause-timeout", "-p", type=float, metavar="SECONDS", help="same as --set pause_timeout_s=SECONDS"
    )
    parser.add_argument("--prompt-id", metavar="ID", help="same as --set prompt_id=ID")
    parser.add_argument("--api-key", help=argparse.SUPPRESS)  # the earlier project's: refused below


def run(args: argparse.Namespace, prog: str = "byc agent") -> int:
    if args.api_key is not None:
        print(f"{prog}: --api-key is not accepted (command lines are visible to every user): "
              "set the key's environment variable (OPENAI_API_KEY, GEMINI_API_KEY)",
              file=sys.stderr)  # fmt: skip
        return EXIT_CONFIG
    assignments = list(args.assignments)
    if args.pause_timeout is not None:
        assignments.append(f"pause_timeout_s={args.pause_timeout!r}")
    if args.prompt_id is not None:
        assignments.append(f"prompt_id={yaml.safe_dump(args.prompt_id).strip()}")
    environ = dict(os.environ)
    try:
        app = load_app_config(args.config, assignments, environ)
        prepared = prepare(app, environ)
    except AgentConfigError as error:
        print(f"{prog}: {error}", file=sys.stderr)
        return EXIT_CONFIG
    if args.check:
        effective = describe(app, prepared.provider.settings, prepared.provider.key_env, environ)
        effective["instructions"] = f"{len(prepared.instructions)} characters (byc prompt shows them)"
        print(f"# {app.source}: valid", flush=True)
        print(yaml.safe_dump(effective, sort_keys=False), end="", flush=True)
        return 0
    setup_logging(app.agent.agent_id, args.verbose, prepared.secrets)
    return run_agent_process(prepared)


def _without_ros_args(argv: list[str]) -> list[str]:
    """`ros2 run` and launch files may append `--ros-args ... [--]`; an agent is no ROS node."""
    if "--ros-args" not in argv:
        return argv
    start = argv.index("--ros-args")
    end = argv.index("--", start) if "--" in argv[start:] else len(argv)
    return argv[:start] + argv[end + 1 :]


def _main(prog: str, default_config: str | None, argv: list[str] | None) -> int:
    parser = argparse.ArgumentParser(
        prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_arguments(parser, default_config)
    args = parser.parse_args(_without_ros_args(sys.argv[1:] if argv is None else argv))
    return run(args, prog)


def main(argv: list[str] | None = None) -> int:
    return _main("byc agent", None, argv)


def main_realtime(argv: list[str] | None = None) -> int:
    """`oai_realtime_agent`: the conversation agent (config/agent_openai.yaml unless -c)."""
    return _main("oai_realtime_agent", REALTIME_CONFIG, argv)


def main_command(argv: list[str] | None = None) -> int:
    """`oai_command_agent`: the dual-mode command agent (config/agent_openai_command.yaml unless -c)."""
    return _main("oai_command_agent", COMMAND_CONFIG, argv)


def main_gemini(argv: list[str] | None = None) -> int:
    """`gemini_live_agent`: the Gemini conversation agent (config/agent_gemini.yaml unless -c)."""
    return _main("gemini_live_agent", GEMINI_CONFIG, argv)


def main_gemini_command(argv: list[str] | None = None) -> int:
    """`gemini_command_agent`: the dual-mode Gemini command agent (config/agent_gemini_command.yaml)."""
    return _main("gemini_command_agent", GEMINI_COMMAND_CONFIG, argv)


if __name__ == "__main__":
    sys.exit(main())
