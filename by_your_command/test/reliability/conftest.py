"""Reliability tests: helpers from this directory and from test/agent_process (agent_graph.py)."""

from __future__ import annotations

import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent
for _path in (str(_HERE), str(_HERE.parent / "agent_process")):
    if _path not in sys.path:
        sys.path.insert(0, _path)
