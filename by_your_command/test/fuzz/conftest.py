"""Hostile-input suite: helpers on the path, a ROS graph node, and the inputs-tried report.

Short mode (default, part of `make test`): few, derandomized examples per target. Long mode
(`BYC_FUZZ_LONG=1`): at least 100k inputs in all; the summary (inputs, failures, time per
target) is printed at the end and written to `$BYC_FUZZ_REPORT` (JSON) when that is set.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from rclpy.node import Node

_HERE = Path(__file__).resolve().parent
for _path in (_HERE, _HERE.parent / "bridge"):  # bridge_fakes: the fake ROS port, running_bridge
    if str(_path) not in sys.path:
        sys.path.insert(0, str(_path))

from fuzzing import LONG, TALLY  # noqa: E402 - needs the path above
from ros_probe import spinning_node  # noqa: E402


@pytest.fixture
def graph_node(ros_namespace: str) -> Iterator[Node]:
    """A node in its own context, spun in a background thread, for tests to publish and listen."""
    with spinning_node(ros_namespace, "fuzz_probe") as node:
        yield node


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if not TALLY:
        return
    rows = TALLY.rows()
    terminalreporter.section(f"hostile inputs ({'long' if LONG else 'short'} mode)")
    for row in rows:
        terminalreporter.write_line(
            f"{row['target']:<34} {row['inputs']:>8} inputs  {row['failures']:>3} failures  "
            f"{row['seconds']:>8.1f} s  median {row['median_ms']:.3f} ms  max {row['max_ms']:.1f} ms"
        )
    total = sum(row["inputs"] for row in rows)
    terminalreporter.write_line(f"{'total':<34} {total:>8} inputs")
    report = os.environ.get("BYC_FUZZ_REPORT")
    if report:
        Path(report).write_text(json.dumps({"long": LONG, "targets": rows, "total": total}, indent=2))
