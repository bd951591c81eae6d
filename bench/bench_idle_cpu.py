"""Idle CPU of the whole offline graph: the robot listening, nobody speaking (goal ≤ 5 % of one core).

`byc up offline` (file source → VAD gating on assistant_speaking + clap → bridge → offline agent,
player, command processor) with the microphone replaced by a looped file of faint room noise at
real time, so every node does its real per-block work. After a warm-up, each process's CPU time
is read from /proc over the measuring window. Same-run baseline: an empty rclpy node spinning
(the floor any ROS process costs here), measured over the same window.

usage: scripts/run.sh python bench/bench_idle_cpu.py [--warmup-s 20] [--measure-s 30] [--set NODE.PARAM=V]
       [--stop-spotter-ab]   # the graph twice, safety stop spotter on then off: its idle cost
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from _proc import Series, process_names, sample_tree

from by_your_command.audio.pcm import write_wav
from by_your_command.demo.child import ChildGraph

GOAL_PERCENT = 5.0
SAMPLE_S = 1.0
EMPTY_NODE = (
    "import rclpy, signal\n"
    "rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)\n"
    "node = rclpy.create_node('idle_baseline')\n"
    "signal.signal(signal.SIGTERM, lambda *_: rclpy.try_shutdown())\n"
    "try:\n    rclpy.spin(node)\nexcept Exception:\n    pass\n"
)


# CPU % of one core per process name in the last measure() (for --stop-spotter-ab).
last_cpu: dict[str, float] = {}


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    record = {"bench": "idle_cpu", "figure": figure, "value": round(value, 3), "unit": unit}
    print(json.dumps({**record, **extra}), flush=True)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def room_noise(path: Path, seconds: float = 10.0) -> None:
    noise = np.random.default_rng(7).normal(0.0, 30.0, int(seconds * 16000))  # about −60 dBFS
    write_wav(path, noise.astype(np.int16), 16000)


async def measure(args: argparse.Namespace, workdir: Path) -> int:
    quiet = workdir / "room_noise.wav"
    room_noise(quiet)
    sets = {
        "audio_source": f"file:{quiet}",
        "audio_sink": f"wav:{workdir / 'robot_said.wav'}",
        "bridge_port": str(free_port()),
        "file_audio_publisher.loop": "true",
    }
    # A namespace of its own: another graph on this machine (a test, a demo) must not cross-talk.
    argv = [sys.executable, "-m", "by_your_command.cli.up", "offline", "--stop-timeout", "20"]
    argv += ["--namespace", f"bench_{os.getpid()}"]
    for key, value in sets.items():
        argv += ["--set", f"{key}={value}"]
    for extra in args.set:  # e.g. file_audio_publisher.chunk_samples=1024: a configuration to compare
        argv += ["--set", extra]
    graph = ChildGraph(argv, workdir / "graph.log")
    baseline = await asyncio.create_subprocess_exec(sys.executable, "-c", EMPTY_NODE)
    series: dict[int, Series] = {}
    started = time.monotonic()
    await graph.start()
    assert graph.pid is not None
    try:
        end = started + args.warmup_s + args.measure_s
        while time.monotonic() < end:
            if graph.exited:
                tail = "\n".join(graph.tail)
                print(f"FAILED: {graph.what_failed()}\n{tail}", file=sys.stderr)
                return 1
            now = time.monotonic() - started
            sample_tree(graph.pid, now, series)
            sample_tree(baseline.pid, now, series)
            await asyncio.sleep(SAMPLE_S)  # the sampling period of a measurement, not a wait for a condition
    finally:
        baseline.kill()  # rclpy.spin ignores SIGTERM here; this process only sets the floor
        await baseline.wait()
        await graph.stop(25.0)
    names = {**process_names(graph.log_path), graph.pid: "byc up", baseline.pid: "empty rclpy node"}
    floor = series[baseline.pid].cpu_percent(since=args.warmup_s)
    total = 0.0
    print(f"\n{'process':24} {'CPU % of one core':>18} {'× empty node':>13}")
    for pid, entry in sorted(series.items(), key=lambda item: names.get(item[0], "")):
        cpu = entry.cpu_percent(since=args.warmup_s)
        name = names.get(pid, f"other[{pid}]")
        ratio = round(cpu / floor, 1) if floor > 0 else None  # an empty node can read 0 ticks
        last_cpu[name] = cpu
        if pid != baseline.pid:
            total += cpu
            emit("process_cpu", cpu, "% of one core", process=name, ratio_to_empty_node=ratio)
        print(f"{name:24} {cpu:18.2f} {'—' if ratio is None else ratio:>13}")
    emit("graph_cpu", total, "% of one core", goal=GOAL_PERCENT, met=total <= GOAL_PERCENT)
    emit("empty_node_cpu", floor, "% of one core")
    print(f"\nwhole offline graph idle: {total:.2f} % of one core (goal ≤ {GOAL_PERCENT} %)")
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--warmup-s", type=float, default=20.0)
    parser.add_argument("--measure-s", type=float, default=30.0)
    parser.add_argument("--set", action="append", default=[], help="NODE.PARAM=VALUE passed to byc up")
    parser.add_argument(
        "--stop-spotter-ab",
        action="store_true",
        help="measure twice, silero_vad_node.stop_spotter on then off, and report the spotter's idle cost",
    )
    args = parser.parse_args()
    if not args.stop_spotter_ab:
        with tempfile.TemporaryDirectory(prefix="byc-idle-") as workdir:
            return asyncio.run(measure(args, Path(workdir)))
    vad: dict[str, float] = {}
    for label, extra in (("on", "true"), ("off", "false")):
        print(f"\n== safety stop spotter {label} ==")
        run_args = argparse.Namespace(
            **{**vars(args), "set": [*args.set, f"silero_vad_node.stop_spotter={extra}"]}
        )
        with tempfile.TemporaryDirectory(prefix="byc-idle-") as workdir:
            if asyncio.run(measure(run_args, Path(workdir))):
                return 1
        vad[label] = last_cpu.get("silero_vad_node", float("nan"))
    cost = vad["on"] - vad["off"]
    emit("stop_spotter_idle_cpu", cost, "% of one core", vad_on=vad["on"], vad_off=vad["off"], goal=1.5)
    print(
        f"\nsafety stop spotter, idle: +{cost:.2f} % of one core "
        f"(VAD node {vad['on']:.2f} vs {vad['off']:.2f})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
