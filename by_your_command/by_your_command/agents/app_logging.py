"""Logging for an agent process: one line per record, prefixed with the agent's id, secrets redacted.

Several agents often share one terminal (`byc up`), so every line names its agent. The formatter
replaces the API key and the bridge token wherever they would appear, tracebacks included: a
library that logs a header or a URL at some level cannot leak them.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterable
from typing import TextIO

REDACTED = "***"
MIN_SECRET_CHARS = 6  # shorter "secrets" (test keys like "x") would redact ordinary text
_HANDLER_NAME = "by_your_command.agent"


class RedactingFormatter(logging.Formatter):
    def __init__(self, fmt: str, secrets: Iterable[str]) -> None:
        super().__init__(fmt, datefmt="%H:%M:%S")
        self._secrets = sorted({s for s in secrets if len(s) >= MIN_SECRET_CHARS}, key=len, reverse=True)

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        for secret in self._secrets:
            text = text.replace(secret, REDACTED)
        return text


def setup_logging(agent_id: str, verbose: bool, secrets: Iterable[str], stream: TextIO | None = None) -> None:
    """Root handler on stderr: INFO, or DEBUG for this package with `verbose` (third-party
    libraries stay at INFO: their debug output is protocol noise, and may quote headers)."""
    handler = logging.StreamHandler(stream or sys.stderr)
    handler.set_name(_HANDLER_NAME)
    handler.setFormatter(
        RedactingFormatter(f"%(asctime)s.%(msecs)03d [agent:{agent_id}] %(levelname)s %(message)s", secrets)
    )
    root = logging.getLogger()
    for old in [h for h in root.handlers if h.get_name() == _HANDLER_NAME]:
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    logging.getLogger("by_your_command").setLevel(logging.DEBUG if verbose else logging.INFO)
