"""Hostile input to the command processor: a 1 MB message, and a `stop` queued behind junk.

In process: `CommandProcessor.process` on ~1 MB messages with the default limits, against the same
processor with the message limit lifted (the unbounded parse, as before the limit; baseline).
In the graph: a command_processor node; the time from publishing `stop` to its verdict on
command_status, alone (baseline) and right behind a burst of 1 MB junk messages, for a node with
the default limits and for one with the limit lifted. Figures as JSON lines, then a table.
usage: scripts/run.sh python bench/bench_command_processor.py [--rounds N] [--burst N]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable
from functools import partial
from typing import Any

UNBOUNDED_CHARS = 1_000_000_000
JUNK = {
    "commas 'a,' x 500k": "a," * 500_000,
    "commands 'lookup, ' x 131k": "lookup, " * 131_072,
    "prefixes 'command:' x 125k": "command:" * 125_000,
    "words with a stop at the end": "hello world " * 83_000 + "\nstop",
}


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    record = {"bench": "command_processor", "figure": figure, "value": round(value, 4), "unit": unit}
    print(json.dumps({**record, **extra}))


def timed_ms(action: Callable[[], object], runs: int) -> list[float]:
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        action()
        times.append((time.perf_counter() - start) * 1000)
    return times


def in_process(runs: int) -> list[tuple[str, list[float]]]:
    from by_your_command.commands.grammar import MessageLimits
    from by_your_command.commands.processor import CommandProcessor
    from by_your_command.commands.safety import SafetyConfig
    from by_your_command.commands.vocabulary import load_vocabulary

    vocabulary = load_vocabulary()
    bounded = CommandProcessor(vocabulary, SafetyConfig(min_interval_s=0.0))
    unbounded = CommandProcessor(
        vocabulary, SafetyConfig(min_interval_s=0.0), MessageLimits(max_message_chars=UNBOUNDED_CHARS)
    )
    rows = []
    for name, message in JUNK.items():
        for label, processor in (("unbounded parse", unbounded), ("bounded", bounded)):
            rows.append((f"{label}: {name}", timed_ms(partial(processor.process, message, 0.0), runs)))
    return rows


class Graph:
    """The bench's side of the graph: publishes response_cmd, times command_status verdicts."""

    def __init__(self, namespace: str) -> None:
        import rclpy
        from by_your_command_msgs.msg import CommandVerdict
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from std_msgs.msg import String

        from by_your_command.nodes import _qos

        self.String = String
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node("bench_commands", namespace=namespace, context=self.context)
        self.publisher = self.node.create_publisher(String, "response_cmd", _qos.RELIABLE)
        self.lock = threading.Lock()
        self.stop_verdicts: list[float] = []
        self.verdicts = 0
        self.node.create_subscription(CommandVerdict, "command_status", self._on_verdict, _qos.RELIABLE)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.spinning = threading.Thread(target=self.executor.spin, daemon=True)
        self.spinning.start()

    def _on_verdict(self, verdict: Any) -> None:
        with self.lock:
            self.verdicts += 1
            if verdict.command == "stop" and verdict.accepted:
                self.stop_verdicts.append(time.monotonic())

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        # A spin still running at exit aborts the interpreter ("terminate called without an
        # active exception": make bench saw it once).
        self.spinning.join(timeout=5)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def stop_latency_ms(self, junk: list[str], timeout: float = 30.0) -> float | None:
        """Publish the junk, then `stop`; ms from the stop's publish to its verdict."""
        with self.lock:
            seen = len(self.stop_verdicts)
        for message in junk:
            self.publisher.publish(self.String(data=message))
        start = time.monotonic()
        self.publisher.publish(self.String(data="stop"))
        deadline = start + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if len(self.stop_verdicts) > seen:
                    return (self.stop_verdicts[seen] - start) * 1000
            time.sleep(0.0005)
        return None


def in_graph(rounds: int, burst: int) -> list[tuple[str, list[float]]]:
    namespace = f"/bench_{uuid.uuid4().hex[:8]}"
    junk = [JUNK["commas 'a,' x 500k"]] * burst
    rows: list[tuple[str, list[float]]] = []
    graph = Graph(namespace)
    try:
        for label, limit in (("bounded", None), ("unbounded", UNBOUNDED_CHARS)):
            args = [sys.executable, "-m", "by_your_command.nodes.command_processor", "--ros-args"]
            args += ["-r", f"__ns:={namespace}", "-p", "min_interval_s:=0.0"]
            if limit is not None:
                args += ["-p", f"max_message_chars:={limit}"]
            process = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            try:
                deadline = time.monotonic() + 30
                while time.monotonic() < deadline and not (
                    graph.publisher.get_subscription_count()
                    and graph.node.count_publishers(f"{namespace}/command_status")
                ):
                    time.sleep(0.05)
                if graph.stop_latency_ms([], timeout=10) is None:  # warm-up: the path works
                    raise RuntimeError("no verdict from command_processor: is the package built?")
                alone = [graph.stop_latency_ms([]) for _ in range(rounds * 4)]
                behind = [graph.stop_latency_ms(junk) for _ in range(rounds)]
                rows.append((f"{label} node: stop alone", [value for value in alone if value is not None]))
                rows.append(
                    (
                        f"{label} node: stop behind {burst} x 1 MB junk",
                        [value for value in behind if value is not None],
                    )
                )
            finally:
                process.terminate()
                try:
                    process.wait(5)
                except subprocess.TimeoutExpired:
                    process.kill()
    finally:
        graph.close()
    return rows


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rounds", type=int, default=5, help="junk bursts per node")
    parser.add_argument("--burst", type=int, default=4, help="1 MB junk messages before each stop")
    args = parser.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rows = in_process(runs=max(3, args.rounds))
    rows += in_graph(args.rounds, args.burst)
    medians = {name: statistics.median(values) for name, values in rows if values}
    for name, values in rows:
        if values:
            emit("latency_p50", statistics.median(values), "ms", path=name, n=len(values))
            emit("latency_max", max(values), "ms", path=name, n=len(values))
    for name in JUNK:
        ratio = medians[f"bounded: {name}"] / medians[f"unbounded parse: {name}"]
        emit("ratio_p50_bounded_vs_unbounded", ratio, "x", message=name)
    for label in ("bounded", "unbounded"):
        behind = medians.get(f"{label} node: stop behind {args.burst} x 1 MB junk")
        alone = medians.get(f"{label} node: stop alone")
        if behind is not None and alone is not None:
            emit("ratio_p50_stop_behind_junk_vs_alone", behind / alone, "x", node=label)
    print()
    print(f"{'path':<58} {'p50 ms':>9} {'max ms':>9} {'n':>4}")
    for name, values in rows:
        if values:
            print(f"{name:<58} {statistics.median(values):>9.3f} {max(values):>9.3f} {len(values):>4}")
        else:
            print(f"{name:<58} {'lost':>9}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
