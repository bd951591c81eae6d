"""`byc emulate openai|gpt-live|gemini`: a local OpenAI Realtime, OpenAI GPT-Live or Gemini Live
server with scripted replies, in the foreground.

Point an agent (or any OpenAI SDK program) at the OpenAI ones with the printed OPENAI_BASE_URL. The
Gemini one serves TLS with a certificate made at start (google-genai only speaks wss://) and prints
the base URL and the certificate to trust. Ctrl-C stops either (and removes the certificate).
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from collections.abc import Coroutine
from pathlib import Path
from typing import Any

from by_your_command.emulators import (
    gemini_live,
    gemini_script,
    gpt_live,
    gpt_live_script,
    openai_realtime,
    openai_script,
)
from by_your_command.emulators.script_common import ScriptError

VENDORS = ("openai", "gpt-live", "gemini")
DEFAULT_PORTS = {"openai": 8765, "gemini": 8766, "gpt-live": 8767}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("vendor", choices=VENDORS, help="which API to emulate")
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default: loopback only)")
    parser.add_argument(
        "--port",
        type=int,
        help="TCP port; 0 picks a free one (default: openai 8765, gemini 8766, gpt-live 8767)",
    )
    parser.add_argument(
        "--script",
        type=Path,
        help="YAML script of replies (format: emulators/{openai,gpt_live,gemini}_script.py)",
    )
    parser.add_argument("--plain", action="store_true", help="gemini: plain ws:// instead of TLS")


async def _serve_openai(host: str, port: int, script: openai_script.Script) -> None:
    emulator = await openai_realtime.start(host, port, script)
    print(f"OpenAI Realtime emulator listening on {emulator.websocket_base_url}/realtime", flush=True)
    print(f"  export OPENAI_BASE_URL={emulator.base_url}", flush=True)
    print(f"  or agent config: websocket_base_url: {emulator.websocket_base_url}", flush=True)
    print("  any API key works (OPENAI_API_KEY=sk-emulator). Ctrl-C stops.", flush=True)
    try:
        await emulator.serve_forever()
    finally:
        await emulator.stop()


async def _serve_gpt_live(host: str, port: int, script: gpt_live_script.Script) -> None:
    emulator = await gpt_live.start(host, port, script)
    print(f"GPT-Live emulator listening on {emulator.websocket_base_url}/live/sessions", flush=True)
    print(f"  export OPENAI_BASE_URL={emulator.base_url}", flush=True)
    print(f"  or agent config: websocket_base_url: {emulator.websocket_base_url}", flush=True)
    print("  any API key works (OPENAI_API_KEY=sk-emulator). Ctrl-C stops.", flush=True)
    try:
        await emulator.serve_forever()
    finally:
        await emulator.stop()


async def _serve_gemini(host: str, port: int, script: gemini_script.Script, tls: bool) -> None:
    emulator = await gemini_live.start(host, port, script, tls=tls)
    print(f"Gemini Live emulator listening on {emulator.websocket_url}", flush=True)
    if emulator.cert_file is not None:
        print(f"  agent config: base_url: {emulator.base_url}  ca_file: {emulator.cert_file}", flush=True)
        print(f"  or: export GOOGLE_GEMINI_BASE_URL={emulator.base_url}", flush=True)
        print(
            "      and trust the certificate above (ca_file, or SSL_CERT_FILE for that process only)",
            flush=True,
        )
    print("  any API key works (GEMINI_API_KEY=emulator). Ctrl-C stops.", flush=True)
    try:
        await emulator.serve_forever()
    finally:
        await emulator.stop()


def _server(args: argparse.Namespace) -> Coroutine[Any, Any, None]:
    """The vendor's server, its script read first (OSError, ScriptError)."""
    if args.vendor == "gemini":
        gemini = gemini_script.load_script(args.script) if args.script else gemini_script.Script()
        return _serve_gemini(args.host, args.port, gemini, tls=not args.plain)
    if args.vendor == "gpt-live":
        live = gpt_live_script.load_script(args.script) if args.script else gpt_live_script.Script()
        return _serve_gpt_live(args.host, args.port, live)
    openai = openai_script.load_script(args.script) if args.script else openai_script.Script()
    return _serve_openai(args.host, args.port, openai)


def run(args: argparse.Namespace) -> int:
    if args.port is None:
        args.port = DEFAULT_PORTS[args.vendor]
    prog = "byc emulate" if args.vendor == "openai" else f"byc emulate {args.vendor}"
    try:
        server = _server(args)
    except (OSError, ScriptError) as error:
        print(f"{prog}: {error}", file=sys.stderr)
        return 2
    try:
        asyncio.run(server)
    except KeyboardInterrupt:
        print("stopped", flush=True)
    except OSError as error:  # port in use, address not available
        print(f"{prog}: cannot listen on {args.host}:{args.port}: {error}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="byc emulate", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
