"""`byc emulate gemini`: a local Gemini Live server with scripted replies, in the foreground.

It serves TLS with a certificate made at start (google-genai only speaks wss://) and prints the
base URL and the certificate to trust; Ctrl-C stops it and removes the certificate.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from by_your_command.cli import emulate


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default: loopback only)")
    parser.add_argument("--port", type=int, default=8766, help="TCP port; 0 picks a free one")
    parser.add_argument(
        "--script", type=Path, help="YAML script of replies (format: emulators/gemini_script.py)"
    )
    parser.add_argument(
        "--plain", action="store_true", help="serve ws:// (raw clients only; the SDK needs TLS)"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="byc emulate gemini", description=__doc__)
    add_arguments(parser)
    return emulate.run(parser.parse_args(argv, argparse.Namespace(vendor="gemini")))


if __name__ == "__main__":
    sys.exit(main())
