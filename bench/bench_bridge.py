"""Bridge latency and overload: ROS → ros_ai_bridge → WebSocket client, against same-run baselines.

Figures (one JSON line each, then a table):
- one-way latency of a 32 ms audio chunk (AudioDataUtterance, 512 samples) published in ROS and
  received (a) by a plain rclpy subscriber (raw DDS) and (b) by our BridgeClient through the bridge,
  for the same messages; the bridge's added cost is (b) - (a) per message;
- (c) a raw websockets server process sending the same JSON frame size to a client (no ROS);
- the publish rate at which the bridge first reports drops to a client that reads as fast as it can.
Clocks: CLOCK_MONOTONIC (time.monotonic_ns) is shared by all processes on the machine.
usage: scripts/run.sh python bench/bench_bridge.py [--messages N]
"""

from __future__ import annotations

import argparse
import array
import asyncio
import json
import os
import re
import statistics
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
BRIDGE = ROOT / "install" / "by_your_command" / "lib" / "by_your_command" / "ros_ai_bridge"
CHUNK_SAMPLES = 512
WARM_UP = 2**32 - 1  # chunk_sequence of messages sent until the path is live (not measured)


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q / 100 * (len(ordered) - 1))))]


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    print(json.dumps({"bench": "bridge", "figure": figure, "value": round(value, 4), "unit": unit, **extra}))


# --- raw websockets baseline (a separate server process) ------------------------------------------


def ws_server_main(count: int, period_s: float, size: int) -> None:
    from websockets.asyncio.server import ServerConnection, serve

    async def handler(connection: ServerConnection) -> None:
        await connection.recv()
        for _ in range(count):
            stamp = time.monotonic_ns()
            frame = f'{{"op":"publish","topic":"prompt_voice","msg":{{"t":{stamp},"pad":"{"x" * size}"}}}}'
            await connection.send(frame)
            await asyncio.sleep(period_s)

    async def main() -> None:
        async with serve(handler, "127.0.0.1", 0, compression=None) as server:
            print(server.sockets[0].getsockname()[1], flush=True)
            await asyncio.sleep(120)

    asyncio.run(main())


def start_ws_server(count: int, period_s: float, size: int) -> tuple[subprocess.Popen[str], int]:
    server = subprocess.Popen(
        [sys.executable, __file__, "--ws-server", str(count), str(period_s), str(size)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert server.stdout is not None
    return server, int(server.stdout.readline())


async def raw_websocket_latencies(port: int, count: int) -> list[float]:
    from websockets.asyncio.client import connect

    latencies = []
    async with connect(f"ws://127.0.0.1:{port}/", compression=None, proxy=None) as connection:
        await connection.send("go")
        for _ in range(count):
            frame = await connection.recv()
            now = time.monotonic_ns()
            stamp = int(json.loads(frame)["msg"]["t"])
            latencies.append((now - stamp) / 1e6)
    return latencies


# --- the bridge ------------------------------------------------------------------------------------


def start_bridge(namespace: str) -> tuple[subprocess.Popen[str], int]:
    process = subprocess.Popen(
        [
            str(BRIDGE),
            "--ros-args",
            "-r",
            f"__ns:={namespace}",
            "-p",
            "port:=0",
            "-p",
            "diagnostics_period_s:=0.0",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert process.stdout is not None
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        match = re.search(r"listening on 127\.0\.0\.1:(\d+)", line)
        if match:
            threading.Thread(target=lambda: [None for _ in process.stdout or []], daemon=True).start()
            return process, int(match.group(1))
        if not line and process.poll() is not None:
            break
    process.kill()
    raise RuntimeError("ros_ai_bridge did not start")


class RosSide:
    """Publisher of audio chunks plus a plain subscriber (the raw DDS baseline), spun in a thread."""

    def __init__(self, namespace: str) -> None:
        import rclpy
        from by_your_command_msgs.msg import AudioDataUtterance
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        from by_your_command.nodes import _qos

        self._msg_type = AudioDataUtterance
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node("bench_bridge", namespace=namespace, context=self.context)
        self.publisher = self.node.create_publisher(AudioDataUtterance, "prompt_voice", _qos.RELIABLE)
        self.dds_latency: dict[int, float] = {}
        self.node.create_subscription(AudioDataUtterance, "prompt_voice", self._on_message, _qos.RELIABLE)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()
        self._pcm = array.array("h", bytes(CHUNK_SAMPLES * 2))

    def _on_message(self, msg: Any) -> None:
        if msg.chunk_sequence == WARM_UP:
            return
        self.dds_latency[msg.chunk_sequence] = (time.monotonic_ns() - msg.utterance_id) / 1e6

    def publish(self, sequence: int) -> None:
        msg = self._msg_type(chunk_sequence=sequence, sample_rate=16000, channels=1)
        msg.int16_data = self._pcm
        msg.utterance_id = time.monotonic_ns()
        self.publisher.publish(msg)

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


async def client_main(port: int, count: int) -> None:
    """The agent side in its own process (no rclpy, like a real agent): print latencies as JSON."""
    from by_your_command.bridge.client import BridgeClient, ClientOptions

    latencies: dict[int, float] = {}
    async with BridgeClient(f"ws://127.0.0.1:{port}/", ClientOptions(receive_queue=100_000)) as client:
        await client.wait_connected(10)
        await client.subscribe("prompt_voice")
        live = False
        while len(latencies) < count:
            msg = (await client.receive(30)).msg
            now = time.monotonic_ns()
            if msg["chunk_sequence"] == WARM_UP:
                if not live:
                    print("live", flush=True)
                    live = True
                continue
            latencies[msg["chunk_sequence"]] = (now - msg["utterance_id"]) / 1e6
    print(json.dumps(latencies), flush=True)


def bridge_latencies(ros: RosSide, port: int, count: int, period_s: float) -> tuple[list[float], list[float]]:
    client = subprocess.Popen(
        [sys.executable, __file__, "--client", str(port), str(count)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert client.stdout is not None
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(client.stdout or []), daemon=True)
        reader.start()
        deadline = time.monotonic() + 30
        while "live\n" not in lines and time.monotonic() < deadline:  # subscription live end to end
            ros.publish(WARM_UP)
            time.sleep(0.05)
        for sequence in range(count):
            ros.publish(sequence)
            time.sleep(period_s)
        reader.join(30)
        measured = {int(k): float(v) for k, v in json.loads(lines[-1]).items()}
    finally:
        client.kill()
        client.wait()
    common = sorted(set(measured) & set(ros.dds_latency))
    return [ros.dds_latency[i] for i in common], [measured[i] for i in common]


async def drop_onset(ros: RosSide, port: int, rates: list[int], seconds: float) -> list[dict[str, float]]:
    from by_your_command.bridge.client import BridgeClient, ClientOptions

    results = []
    async with BridgeClient(f"ws://127.0.0.1:{port}/", ClientOptions(receive_queue=1_000_000)) as client:
        await client.wait_connected(10)
        await client.subscribe("prompt_voice")
        while client.receive_nowait() is None:
            ros.publish(WARM_UP)
            await asyncio.sleep(0.05)
        sequence = 1_000_000
        for rate in rates:
            before_drops = sum(sum(s.counts.values()) for s in client.statuses if s.code == "dropped")
            received = 0
            sent = 0
            start = time.monotonic()
            while time.monotonic() - start < seconds:
                target = int((time.monotonic() - start) * rate)
                while sent < target:
                    ros.publish(sequence)
                    sequence += 1
                    sent += 1
                while client.receive_nowait() is not None:
                    received += 1
                await asyncio.sleep(0.001)
            settle = time.monotonic() + 2.0
            while received < sent and time.monotonic() < settle:
                if client.receive_nowait() is not None:
                    received += 1
                else:
                    await asyncio.sleep(0.01)
            drops = sum(sum(s.counts.values()) for s in client.statuses if s.code == "dropped") - before_drops
            achieved = sent / seconds
            results.append(
                {
                    "rate": float(rate),
                    "achieved": achieved,
                    "sent": sent,
                    "received": received,
                    "bridge_reported_drops": drops,
                }
            )
            if received < sent:
                break
    return results


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--messages", type=int, default=400)
    parser.add_argument("--period-ms", type=float, default=5.0)
    parser.add_argument("--ws-server", nargs=3, help=argparse.SUPPRESS)
    parser.add_argument("--client", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.ws_server:
        ws_server_main(int(args.ws_server[0]), float(args.ws_server[1]), int(args.ws_server[2]))
        return 0
    if args.client:
        asyncio.run(client_main(int(args.client[0]), int(args.client[1])))
        return 0
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    namespace = f"/bench_{uuid.uuid4().hex[:8]}"
    period = args.period_ms / 1000
    bridge, port = start_bridge(namespace)
    ros = RosSide(namespace)
    try:
        dds, via_bridge = bridge_latencies(ros, port, args.messages, period)
        frame_size = 512 * 5  # JSON of 512 int16 samples is about 2.5-3 KB
        ws_server, ws_port = start_ws_server(args.messages, period, frame_size)
        try:
            raw_ws = asyncio.run(raw_websocket_latencies(ws_port, args.messages))
        finally:
            ws_server.kill()
            ws_server.wait()
        onset = asyncio.run(drop_onset(ros, port, [500, 1000, 2000, 4000, 8000], 1.0))
    finally:
        ros.close()
        bridge.terminate()
        try:
            bridge.wait(5)
        except subprocess.TimeoutExpired:
            bridge.kill()
    added = [b - d for d, b in zip(dds, via_bridge, strict=True)]
    rows = []
    for name, values in (
        ("raw DDS (rclpy sub)", dds),
        ("raw websockets", raw_ws),
        ("ROS→bridge→client", via_bridge),
        ("bridge added (per msg)", added),
    ):
        p50, p99 = statistics.median(values), percentile(values, 99)
        emit("latency_p50", p50, "ms", path=name, n=len(values))
        emit("latency_p99", p99, "ms", path=name, n=len(values))
        rows.append((name, p50, p99, len(values)))
    emit("ratio_p50_bridge_vs_dds", statistics.median(via_bridge) / statistics.median(dds), "x")
    for step in onset:
        emit("overload_step", step["received"] / max(1, step["sent"]), "fraction_received", **step)
    first_drop = next((s["achieved"] for s in onset if s["received"] < s["sent"]), None)
    emit(
        "drops_start_at",
        first_drop if first_drop is not None else float("nan"),
        "msg/s",
        note="publish rate of the first step with loss (NaN: none up to the highest step)",
    )
    print()
    print(f"{'path':<26} {'p50 ms':>8} {'p99 ms':>8} {'n':>6}")
    for name, p50, p99, n in rows:
        print(f"{name:<26} {p50:>8.3f} {p99:>8.3f} {n:>6}")
    print(f"\n{'rate msg/s':>10} {'achieved':>9} {'sent':>7} {'received':>9} {'reported drops':>15}")
    for step in onset:
        print(
            f"{step['rate']:>10.0f} {step['achieved']:>9.0f} {step['sent']:>7.0f} {step['received']:>9.0f} "
            f"{step['bridge_reported_drops']:>15.0f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
