"""`byc emulate openai`: a local OpenAI Realtime server with scripted replies, in the foreground.

Point an agent (or any OpenAI SDK program) at it with the printed OPENAI_BASE_URL; Ctrl-C stops it.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from by_your_command.cli import emulate_gemini
from by_your_command.emulators.openai_realtime import start
from by_your_command.emulators.openai_script import Script, ScriptError, load_script

VENDORS = ("openai", "gemini")
DEFAULT_PORTS = {"openai": 8765, "gemini": 8766}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("vendor", choices=VENDORS, help="which API to emulate")
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default: loopback only)")
    parser.add_argument(
        "--port", type=int, help="TCP port; 0 picks a free one (default: openai 8765, gemini 8766)"
    )
    parser.add_argument(
        "--script", type=Path, help="YAML script of replies (format: emulators/<vendor>_script.py)"
    )
    parser.add_argument("--plain", action="store_true", help="gemini: plain ws:// instead of TLS")


async def _serve(host: str, port: int, script: Script) -> None:
    emulator = await start(host, port, script)
    print(f"OpenAI Realtime emulator listening on {emulator.websocket_base_url}/realtime", flush=True)
    print(f"  export OPENAI_BASE_URL={emulator.base_url}", flush=True)
    print(f"  or agent config: websocket_base_url: {emulator.websocket_base_url}", flush=True)
    print("  any API key works (OPENAI_API_KEY=sk-emulator). Ctrl-C stops.", flush=True)
    try:
        await emulator.serve_forever()
    finally:
        await emulator.stop()


def run(args: argparse.Namespace) -> int:
    if args.port is None:
        args.port = DEFAULT_PORTS[args.vendor]
    if args.vendor == "gemini":
        return emulate_gemini.run(args)
    try:
        script = load_script(args.script) if args.script else Script()
    except (OSError, ScriptError) as error:
        print(f"byc emulate: {error}", file=sys.stderr)
        return 2
    try:
        asyncio.run(_serve(args.host, args.port, script))
    except KeyboardInterrupt:
        print("stopped", flush=True)
    except OSError as error:  # port in use, address not available
        print(f"byc emulate: cannot listen on {args.host}:{args.port}: {error}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="byc emulate", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
