"""Memory of the audio nodes under a fast audio stream: RSS growth per 10,000 messages.

The audio front end's nodes (file_audio_publisher → echo_suppressor (gate; aec mode's hop) →
silero_vad_node, and clap_detector_node on `audio`), each node in its own process, the corpus
looped at `--rate` times real time (31.25 blocks of 512 samples a second at 1×). Same-run baseline:
a bare rclpy publisher and subscriber (rclpy.spin, no code of ours) carrying the same AudioChunk
traffic at the same rate. One more bare subscriber is spun the way run_node spun nodes before the
fix, by `Executor.spin_until_future_complete(Future())`: rclpy keeps one wake-up callback per
callback run on that future (~250 bytes per message; ros2/rclpy#1374), so this line shows whether
the installed rclpy still has the bug that nodes/_runtime._StopFuture works around.

After `--warmup-s`, each process's RSS is read from /proc every second for `--measure-s`; the
figure is the least-squares slope of RSS against the messages published on the stream (nominal
rate), in MB per 10k messages. The soak (bench/soak.py) sees the same thing over an hour.

usage: scripts/run.sh python bench/bench_memory.py [--rate 8] [--warmup-s 20] [--measure-s 60]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from _proc import Series, sample_tree

CORPUS_WAV = Path(__file__).resolve().parents[1] / "by_your_command/test/data/corpus/clean_en_us.wav"
BLOCK = 512
SAMPLE_RATE = 16000
SAMPLE_S = 1.0
PER = 10_000  # messages
# Above the worse bare process by this much (MB per 10k messages = 10 bytes per message): a leak.
LEAK_MARGIN_MB = 0.1

BARE = """
import array, sys, rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.task import Future
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk
from rclpy.qos import QoSProfile, QoSReliabilityPolicy
kind, period = sys.argv[1], float(sys.argv[2])
rclpy.init(args=sys.argv)
node = rclpy.create_node("bare_" + kind)
qos = QoSProfile(depth=64, reliability=QoSReliabilityPolicy.BEST_EFFORT)
if kind == "publisher":
    pub = node.create_publisher(AudioChunk, "bare_audio", qos)
    samples = array.array("h", range(512))
    count = [0]
    def tick():
        count[0] += 1
        ns = count[0] * 32_000_000
        msg = AudioChunk(sample_rate=16000, channels=1, data=samples)
        msg.header.stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        pub.publish(msg)
    node.create_timer(period, tick)
else:
    node.create_subscription(AudioChunk, "bare_audio", lambda msg: len(msg.data), qos)
executor = SingleThreadedExecutor()
executor.add_node(node)
if kind == "spin_until_future_complete":
    executor.spin_until_future_complete(Future())
else:
    executor.spin()
"""


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    record = {"bench": "memory", "figure": figure, "value": round(value, 4), "unit": unit}
    print(json.dumps({**record, **extra}), flush=True)


def node(module: str, namespace: str, *params: str) -> list[str]:
    args = [sys.executable, "-m", f"by_your_command.nodes.{module}", "--ros-args", "-r", f"__ns:={namespace}"]
    for param in params:
        args += ["-p", param]
    return args


def bare(kind: str, namespace: str, period: float) -> list[str]:
    return [sys.executable, "-c", BARE, kind, str(period), "--ros-args", "-r", f"__ns:={namespace}"]


def commands(namespace: str, rate: float) -> dict[str, list[str]]:
    period = BLOCK / SAMPLE_RATE / rate
    return {
        "file_audio_publisher": node(
            "file_audio_publisher",
            namespace,
            f"files:=[{CORPUS_WAV}]",
            "loop:=true",
            f"rate_factor:={float(rate)}",
            "min_subscribers:=2",
            "wait_for_topic:=audio_filtered",
        ),  # fmt: skip
        "echo_suppressor": node("echo_suppressor", namespace, "mode:=gate"),
        "clap_detector_node": node("clap_detector_node", namespace),
        # Spoken wake only decodes while asleep; off, the VAD does not load a recognizer it never uses.
        "silero_vad_node": node("silero_vad_node", namespace, "spoken_wake:=false"),
        "bare rclpy publisher": bare("publisher", namespace, period),
        "bare rclpy subscriber": bare("subscriber", namespace, period),
        "bare spin_until_future_complete": bare("spin_until_future_complete", namespace, period),
    }


def slope_per_10k(entry: Series, since: float, messages_per_s: float) -> float:
    picked = [i for i, at in enumerate(entry.times) if at >= since]
    if len(picked) < 3:
        return float("nan")
    times = np.asarray([entry.times[i] for i in picked])
    rss = np.asarray([entry.rss_mb[i] for i in picked])
    mb_per_s = float(np.polyfit(times, rss, 1)[0])
    return mb_per_s / messages_per_s * PER


def measure(args: argparse.Namespace, workdir: Path) -> int:
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    namespace = f"/bench_memory_{os.getpid()}"
    messages_per_s = SAMPLE_RATE / BLOCK * args.rate
    processes: dict[str, subprocess.Popen[bytes]] = {}
    logs = {name: workdir / f"{name.replace(' ', '_')}.log" for name in commands(namespace, args.rate)}
    series: dict[str, Series] = {}
    try:
        for name, command in commands(namespace, args.rate).items():
            with logs[name].open("wb") as log:
                processes[name] = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT)
        started = time.monotonic()
        end = started + args.warmup_s + args.measure_s
        while time.monotonic() < end:
            for name, process in processes.items():
                if process.poll() is not None:
                    tail = logs[name].read_text(errors="replace")[-3000:]
                    print(f"FAILED: {name} exited with {process.returncode}\n{tail}", file=sys.stderr)
                    return 1
                found: dict[int, Series] = {}
                sample_tree(process.pid, time.monotonic() - started, found)
                if process.pid in found:
                    entry = series.setdefault(name, Series())
                    entry.times += found[process.pid].times
                    entry.rss_mb += found[process.pid].rss_mb
                    entry.cpu_s += found[process.pid].cpu_s
            time.sleep(SAMPLE_S)  # the sampling period of a measurement, not a wait for a condition
    finally:
        for process in processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGINT)  # run_node stops cleanly; the bare ones end at once
        for process in processes.values():
            try:
                process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
    report(series, args, messages_per_s)
    return 0


def report(series: dict[str, Series], args: argparse.Namespace, messages_per_s: float) -> None:
    since = args.warmup_s
    growth = {name: slope_per_10k(entry, since, messages_per_s) for name, entry in series.items()}
    rows = []
    for name, entry in series.items():
        start = next(rss for at, rss in zip(entry.times, entry.rss_mb, strict=True) if at >= since)
        per_message = growth[name] * 2**20 / PER
        cpu = entry.cpu_percent(since=since)
        emit(
            "rss_growth", growth[name], "MB per 10k messages", process=name,
            bytes_per_message=round(per_message), rss_start_mb=round(start, 1),
            rss_end_mb=round(entry.rss_mb[-1], 1), cpu_percent=round(cpu, 1),
        )  # fmt: skip
        end = entry.rss_mb[-1]
        rows.append(f"{name:34} {start:7.1f} {end:7.1f} {growth[name]:12.3f} {per_message:6.0f} {cpu:6.1f}")
    measured = f"{args.measure_s:.0f} s measured after {args.warmup_s:.0f} s of warm-up"
    print(f"\n{messages_per_s:.0f} messages/s, {measured}")
    print(f"{'process':34} {'RSS MB':>7} {'end MB':>7} {'MB/10k msgs':>12} {'B/msg':>6} {'CPU %':>6}")
    print("\n".join(rows))
    floor = max(growth["bare rclpy publisher"], growth["bare rclpy subscriber"])
    audio = [name for name in growth if not name.startswith("bare")]
    worst = max(audio, key=lambda name: growth[name])
    excess = growth[worst] - floor
    emit(
        "audio_node_excess", excess, "MB per 10k messages", process=worst,
        baseline=round(floor, 4), goal=LEAK_MARGIN_MB, met=excess <= LEAK_MARGIN_MB,
    )  # fmt: skip
    upstream = growth["bare spin_until_future_complete"] - floor > LEAK_MARGIN_MB
    emit("rclpy_spin_until_future_complete_leaks", float(upstream), "bool")
    print(
        f"\nworst audio node: {worst}, {excess:+.3f} MB per 10k messages over bare rclpy "
        f"(goal ≤ {LEAK_MARGIN_MB}); rclpy's spin_until_future_complete "
        f"{'still leaks (keep _runtime._StopFuture)' if upstream else 'does not leak here'}"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=8.0, help="how much faster than real time")
    parser.add_argument("--warmup-s", type=float, default=20.0)
    parser.add_argument("--measure-s", type=float, default=60.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="byc-memory-") as workdir:
        return measure(args, Path(workdir))


if __name__ == "__main__":
    sys.exit(main())
