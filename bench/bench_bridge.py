"""Bridge latency, overload accounting and heavy-client isolation, against same-run baselines.

Figures (one JSON line each, then tables):
- one-way latency of a 32 ms audio chunk (AudioDataUtterance, 512 samples) published in ROS and
  received (a) by a plain rclpy subscriber (raw DDS) and (b) by our BridgeClient through the bridge,
  for the same messages; the bridge's added cost is (b) - (a) per message;
- (c) a raw websockets server process sending the same JSON frame size to a client (no ROS);
- overload: at 500..8000 chunks/s for one second each, sent / delivered / reported lost (the
  bridge's `lost` and `dropped` statuses) / unaccounted (must be 0: every loss is reported);
- heavy client: latency of a light client's 40 ms `response_voice` chunks (WebSocket → ROS) alone
  and while another client publishes ~0.9 MB chunks, with large conversions on worker threads
  (default) and, as the "before" baseline in the same run, all on the event loop
  (`inline_convert_bytes` huge).
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


def start_bridge(namespace: str, *params: str) -> tuple[subprocess.Popen[str], int]:
    extra = [arg for param in params for arg in ("-p", param)]
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
            *extra,
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
        from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance
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
        self.voice_latency: list[float] = []  # light client's response_voice chunks, WebSocket → ROS
        self.node.create_subscription(AudioChunk, "response_voice", self._on_voice, _qos.RELIABLE)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()
        self._pcm = array.array("h", bytes(CHUNK_SAMPLES * 2))

    def _on_voice(self, msg: Any) -> None:
        if msg.stream_id.startswith("light "):
            self.voice_latency.append((time.monotonic_ns() - int(msg.stream_id[6:])) / 1e6)

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
            delivery = await client.receive(30)
            now = time.monotonic_ns()
            msg = getattr(delivery, "msg", None)
            if msg is None:  # a loss report: not a latency sample
                continue
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


async def poll_until(condition: Any, timeout: float) -> None:
    """Settle: give in-flight messages up to `timeout` s to arrive (a bench, not a test)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        await asyncio.sleep(0.01)


async def overload_accounting(
    ros: RosSide, port: int, rates: list[int], seconds: float
) -> list[dict[str, float]]:
    """Publish at each rate for `seconds`; count what arrives and what the bridge reports lost."""
    from websockets.asyncio.client import connect

    results = []
    counts = {"delivered": 0, "reported": 0}

    async def read(connection: Any) -> None:
        async for text in connection:
            frame = json.loads(text)
            if frame["op"] == "publish" and frame["msg"]["chunk_sequence"] != WARM_UP:
                counts["delivered"] += 1
            elif frame["op"] == "status" and frame.get("code") in ("lost", "dropped"):
                counts["reported"] += sum(frame["counts"].values())

    async with connect(f"ws://127.0.0.1:{port}/", compression=None, max_size=None) as connection:
        await connection.send('{"op":"subscribe","topic":"prompt_voice"}')
        while True:  # path live end to end: one warm-up message arrives
            ros.publish(WARM_UP)
            try:
                json.loads(await asyncio.wait_for(connection.recv(), 0.1))
                break
            except asyncio.TimeoutError:  # noqa: UP041 - not the builtin TimeoutError before 3.11
                continue
        reader = asyncio.create_task(read(connection))
        sequence = 1_000_000
        for rate in rates:
            counts.update(delivered=0, reported=0)
            sent = 0
            start = time.monotonic()
            while time.monotonic() - start < seconds:
                target = int((time.monotonic() - start) * rate)
                while sent < target:
                    ros.publish(sequence)
                    sequence += 1
                    sent += 1
                await asyncio.sleep(0.001)
            await poll_until(lambda sent=sent: counts["delivered"] + counts["reported"] >= sent, 5.0)
            results.append(
                {
                    "rate": float(rate),
                    "achieved": sent / seconds,
                    "sent": sent,
                    "delivered": counts["delivered"],
                    "reported_lost": counts["reported"],
                    "unaccounted": sent - counts["delivered"] - counts["reported"],
                }
            )
        reader.cancel()
    return results


def heavy_chunk_frame(samples: int) -> str:
    import random

    rng = random.Random(7)
    data = [rng.randint(-32768, 32767) for _ in range(samples)]
    msg = {"sample_rate": 24000, "channels": 1, "stream_id": "heavy", "data": data}
    return json.dumps({"op": "publish", "topic": "response_voice", "msg": msg}, separators=(",", ":"))


async def light_latencies(ros: RosSide, port: int, seconds: float, heavy_clients: int) -> list[float]:
    """A light client sends a 40 ms chunk every 20 ms while `heavy_clients` publish ~0.9 MB chunks."""
    from websockets.asyncio.client import connect

    url = f"ws://127.0.0.1:{port}/"
    heavy = heavy_chunk_frame(130_000)
    samples = [0] * 960
    stop = asyncio.Event()

    async def push_heavy() -> None:
        async with connect(url, compression=None, max_size=None) as connection:
            while not stop.is_set():
                await connection.send(heavy)  # as fast as the bridge reads (it applies back-pressure)

    heavy_tasks = [asyncio.create_task(push_heavy()) for _ in range(heavy_clients)]
    ros.voice_latency.clear()
    async with connect(url, compression=None) as light:
        end = time.monotonic() + seconds
        sent = 0
        while time.monotonic() < end:
            msg = {
                "sample_rate": 24000,
                "channels": 1,
                "stream_id": f"light {time.monotonic_ns()}",
                "data": samples,
            }
            await light.send(json.dumps({"op": "publish", "topic": "response_voice", "msg": msg}))
            sent += 1
            await asyncio.sleep(0.02)
        await poll_until(lambda: len(ros.voice_latency) >= sent, 5.0)
    stop.set()
    for task in heavy_tasks:
        task.cancel()
    await asyncio.gather(*heavy_tasks, return_exceptions=True)
    return list(ros.voice_latency)


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
        onset = asyncio.run(overload_accounting(ros, port, [500, 1000, 2000, 4000, 8000], 1.0))
        heavy: dict[str, list[float]] = {
            "light alone": asyncio.run(light_latencies(ros, port, 2.0, 0)),
            "with 2 heavy, workers": asyncio.run(light_latencies(ros, port, 3.0, 2)),
        }
        inline_bridge, inline_port = start_bridge(namespace + "_inline", "inline_convert_bytes:=100000000")
        inline_ros = RosSide(namespace + "_inline")
        try:
            heavy["with 2 heavy, on loop"] = asyncio.run(light_latencies(inline_ros, inline_port, 3.0, 2))
        finally:
            inline_ros.close()
            stop_process(inline_bridge)
    finally:
        ros.close()
        stop_process(bridge)
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
        emit("overload_step", step["delivered"] / max(1, step["sent"]), "fraction_delivered", **step)
    first_drop = next((s["achieved"] for s in onset if s["delivered"] < s["sent"]), None)
    emit(
        "drops_start_at",
        first_drop if first_drop is not None else float("nan"),
        "msg/s",
        note="publish rate of the first step with loss (NaN: none up to the highest step)",
    )
    emit("unaccounted_total", sum(s["unaccounted"] for s in onset), "messages", note="must be 0")
    alone_p50 = statistics.median(heavy["light alone"]) if heavy["light alone"] else float("nan")
    heavy_rows = []
    for name, values in heavy.items():
        if not values:
            continue
        p50, p99 = statistics.median(values), percentile(values, 99)
        emit(
            "light_publish_p50", p50, "ms", path=name, n=len(values), ratio_vs_alone=round(p50 / alone_p50, 2)
        )
        emit("light_publish_p99", p99, "ms", path=name, n=len(values))
        heavy_rows.append((name, p50, p99, max(values), len(values)))
    print()
    print(f"{'path':<26} {'p50 ms':>8} {'p99 ms':>8} {'n':>6}")
    for name, p50, p99, n in rows:
        print(f"{name:<26} {p50:>8.3f} {p99:>8.3f} {n:>6}")
    print(f"\n{'rate msg/s':>10} {'sent':>7} {'delivered':>10} {'reported lost':>14} {'unaccounted':>12}")
    for step in onset:
        print(
            f"{step['rate']:>10.0f} {step['sent']:>7.0f} {step['delivered']:>10.0f} "
            f"{step['reported_lost']:>14.0f} {step['unaccounted']:>12.0f}"
        )
    print(f"\n{'light client publish (ms)':<26} {'p50':>8} {'p99':>8} {'max':>8} {'n':>6}")
    for name, p50, p99, worst, n in heavy_rows:
        print(f"{name:<26} {p50:>8.3f} {p99:>8.3f} {worst:>8.3f} {n:>6}")
    return 0


def stop_process(process: subprocess.Popen[str]) -> None:
    process.terminate()
    try:
        process.wait(5)
    except subprocess.TimeoutExpired:
        process.kill()


if __name__ == "__main__":
    sys.exit(main())
