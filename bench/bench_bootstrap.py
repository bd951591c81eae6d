"""Wall time of a bootstrap with nothing to do (every `make` target starts with one), against baselines.

Baselines measured in the same run: starting bash (`bash -c true`) and the venv's Python (`python -c
pass`; it execs twice because of the ROS wheels' start-up hook). The checkout must be bootstrapped
already: a run that does work (installs, builds) is reported and fails the bench, it is not timed.
Figures as JSON lines, then a table. The budget (BUDGET_S) is what a no-op run may cost at most.
usage: scripts/run.sh python bench/bench_bootstrap.py [--runs N]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
BOOTSTRAP = ROOT / "scripts" / "bootstrap.sh"
BUDGET_S = 2.0


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    print(
        json.dumps({"bench": "bootstrap", "figure": figure, "value": round(value, 4), "unit": unit, **extra})
    )


def timed(args: list[str]) -> tuple[float, str]:
    start = time.perf_counter()
    result = subprocess.run(args, capture_output=True, text=True, check=True)
    return time.perf_counter() - start, result.stdout


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    commands = {
        "bootstrap.sh (nothing to do)": ["bash", str(BOOTSTRAP)],
        "baseline: bash -c true": ["bash", "-c", "true"],
        "baseline: venv python -c pass": [str(ROOT / ".venv" / "bin" / "python"), "-c", "pass"],
    }
    seconds: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(args.runs):
        for name, command in commands.items():
            elapsed, stdout = timed(command)
            if command[1] == str(BOOTSTRAP) and stdout.strip() != "bootstrap: ready":
                print(f"bootstrap did work, so it is not timed:\n{stdout}", file=sys.stderr)
                return 1
            seconds[name].append(elapsed)
    for name, values in seconds.items():
        emit(name, statistics.median(values), "s", max=round(max(values), 4), runs=len(values))
    print()
    print(f"{'command':<32} {'p50 s':>8} {'max s':>8} {'n':>4}")
    for name, values in seconds.items():
        print(f"{name:<32} {statistics.median(values):>8.3f} {max(values):>8.3f} {len(values):>4}")
    worst = max(seconds["bootstrap.sh (nothing to do)"])
    print(f"\nno-op bootstrap, slowest run: {worst:.3f} s (budget {BUDGET_S} s)")
    return 0 if worst <= BUDGET_S else 1


if __name__ == "__main__":
    sys.exit(main())
