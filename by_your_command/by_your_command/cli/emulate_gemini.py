"""`byc emulate gemini`: a local Gemini Live server with scripted replies, in the foreground.

It serves TLS with a certificate made at start (google-genai only speaks wss://) and prints the
base URL and the certificate to trust; Ctrl-C stops it and removes the certificate.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path

from by_your_command.emulators.gemini_live import start
from by_your_command.emulators.gemini_script import Script, ScriptError, load_script


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default: loopback only)")
    parser.add_argument("--port", type=int, default=8766, help="TCP port; 0 picks a free one")
    parser.add_argument(
        "--script", type=Path, help="YAML script of replies (format: emulators/gemini_script.py)"
    )
    parser.add_argument(
        "--plain", action="store_true", help="serve ws:// (raw clients only; the SDK needs TLS)"
    )


async def _serve(host: str, port: int, script: Script, tls: bool) -> None:
    emulator = await start(host, port, script, tls=tls)
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


def run(args: argparse.Namespace) -> int:
    try:
        script = load_script(args.script) if args.script else Script()
    except (OSError, ScriptError) as error:
        print(f"byc emulate gemini: {error}", file=sys.stderr)
        return 2
    try:
        asyncio.run(_serve(args.host, args.port, script, tls=not getattr(args, "plain", False)))
    except KeyboardInterrupt:
        print("stopped", flush=True)
    except OSError as error:  # port in use, address not available
        print(f"byc emulate gemini: cannot listen on {args.host}:{args.port}: {error}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="byc emulate gemini", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
