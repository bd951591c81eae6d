"""Monitor tests: helpers from this directory (the CDP driver, the in-process bridge)."""

from __future__ import annotations

import sys
from pathlib import Path

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)

from browser_helpers import browser  # noqa: E402, F401  (the headless Chromium fixture, shared)
