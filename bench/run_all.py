"""`make bench`: run every bench/bench_*.py and write one summary of their figures.

Each script prints its figures as JSON lines ({"bench": ..., "figure": ..., ...}) among its own
table; this runner shows the scripts' output as it comes, collects those lines, and writes
summary.json (every figure, per script, with its status and wall time) and summary.md (one table
per script) into --out (default out/bench, ignored by git). The soak (bench/soak.py, an hour of
conversation compressed into about 16 minutes) is not part of it: run it on its own.

usage: scripts/run.sh python bench/run_all.py [--only vad,bridge] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
MAX_DETAIL_CHARS = 160


def run_script(script: Path) -> tuple[int, float, list[dict[str, Any]]]:
    """Run one benchmark, echoing its output; (exit status, wall seconds, its JSON figures)."""
    started = time.monotonic()
    figures: list[dict[str, Any]] = []
    with subprocess.Popen(
        [sys.executable, str(script)], stdout=subprocess.PIPE, text=True, cwd=ROOT
    ) as process:
        assert process.stdout is not None
        for line in process.stdout:
            print(line, end="", flush=True)
            if line.startswith("{"):
                try:
                    record = json.loads(line)
                except ValueError:
                    continue
                if isinstance(record, dict) and "bench" in record:
                    figures.append(record)
    return process.returncode, time.monotonic() - started, figures


def _value(record: dict[str, Any]) -> str:
    if "value" in record:
        return str(record["value"])
    stats = [f"{key} {record[key]}" for key in ("median", "p50", "p95", "p99", "mean") if key in record]
    return ", ".join(stats) or "–"


def _details(record: dict[str, Any]) -> str:
    skip = {"bench", "figure", "value", "unit", "median", "p50", "p95", "p99", "mean"}
    text = ", ".join(f"{key}={value}" for key, value in record.items() if key not in skip)
    text = text.replace("|", "/")
    return text if len(text) <= MAX_DETAIL_CHARS else text[: MAX_DETAIL_CHARS - 1] + "…"


def markdown(results: dict[str, dict[str, Any]]) -> str:
    generated = time.strftime("%Y-%m-%d %H:%M:%S")
    lines = ["# Benchmark summary", "", f"Generated {generated} by bench/run_all.py.", ""]
    for name, result in results.items():
        status = "ok" if result["status"] == 0 else f"FAILED (exit {result['status']})"
        lines += [f"## {name} — {status}, {result['wall_s']:.0f} s", ""]
        if not result["figures"]:
            lines += ["(no figures)", ""]
            continue
        lines += ["| figure | value | unit | details |", "|---|---|---|---|"]
        for record in result["figures"]:
            figure = record.get("figure", record.get("name", "–"))
            lines.append(f"| {figure} | {_value(record)} | {record.get('unit', '')} | {_details(record)} |")
        lines.append("")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", default="", help="comma-separated names (vad for bench_vad.py)")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    args = parser.parse_args()
    wanted = {name.strip() for name in args.only.split(",") if name.strip()}
    scripts = sorted(Path(__file__).parent.glob("bench_*.py"))
    scripts = [s for s in scripts if not wanted or s.stem.removeprefix("bench_") in wanted]
    if not scripts:
        print("no benchmark matches", file=sys.stderr)
        return 2
    results: dict[str, dict[str, Any]] = {}
    for script in scripts:
        print(f"\n=== {script.name} ===", flush=True)
        status, wall_s, figures = run_script(script)
        results[script.stem] = {"status": status, "wall_s": round(wall_s, 1), "figures": figures}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(results, indent=1))
    (args.out / "summary.md").write_text(markdown(results))
    failed = [name for name, result in results.items() if result["status"] != 0]
    print(f"\nsummary: {args.out / 'summary.md'} and summary.json ({len(results)} benchmarks)")
    if failed:
        print(f"failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
