"""`publish_command`: send command text to the command processor by hand and show its verdicts.

publish_command "pan@left" "good morning" --namespace /grunt1
"""

from __future__ import annotations

import argparse
import importlib
import sys


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="publish_command", description="publish text on response_cmd")
    parser.add_argument(
        "texts", nargs="+", metavar="TEXT", help="one message per TEXT (may hold several commands)"
    )
    parser.add_argument("--topic", default="response_cmd", help="topic to publish on (default: %(default)s)")
    parser.add_argument(
        "--status-topic", default="command_status", help="verdict topic (default: %(default)s)"
    )
    parser.add_argument("--namespace", default="", help="ROS namespace, e.g. /grunt1")
    parser.add_argument("--no-wait", action="store_true", help="do not wait for verdicts")
    parser.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the processor")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # Loaded at run time: this module (and --help) must import where ROS is absent, and the rclpy
    # half lives under nodes/, outside the strictly typed core.
    ros_side = importlib.import_module("by_your_command.nodes.publish_command")
    try:
        verdicts = ros_side.publish_commands(
            args.texts, args.topic, args.status_topic, args.namespace, not args.no_wait, args.timeout
        )
    except ros_side.NoSubscriber as error:
        print(f"publish_command: {error}", file=sys.stderr)
        return 1
    for verdict in verdicts:
        mark = "accepted" if verdict.accepted else "REFUSED "
        target = f" -> {verdict.topic}" if verdict.accepted else ""
        print(f"{mark}  {verdict.raw!r}  {verdict.command or '-'}{target}  ({verdict.reason})")
    if not args.no_wait and not verdicts:
        print("publish_command: no verdict received", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
