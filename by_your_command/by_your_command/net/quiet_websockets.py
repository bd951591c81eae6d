"""The logger to give websockets, so handshake headers (API keys, the bridge token) never reach a log.

websockets logs every handshake's request and response headers at DEBUG. A logger whose own level is
INFO stops those records before any handler sees them, even when the root logger is at DEBUG.
"""

from __future__ import annotations

import logging


def quiet_websocket_logger(owner: str) -> logging.Logger:
    """`<owner>.websocket`, a logger that never logs at DEBUG: pass it as websockets' `logger`."""
    logger = logging.getLogger(f"{owner}.websocket")
    logger.setLevel(logging.INFO)
    return logger
