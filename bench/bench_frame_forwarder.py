"""Trigger → forwarded-frame latency of the frame_forwarder node, and the cost of hostile frames.

The bench publishes 640x480 rgb8 frames, then a `voice_activity` True trigger, and times the
arrival of `camera_forwarded`. Baselines measured in the same run: the JPEG encode of the same
frame in this process (the work the node must do), and the DDS one-way latency of the trigger
itself (a Bool to a plain subscriber).
Hostile frames, in process: refusing a decompression bomb (a ~100-byte PNG/JPEG declaring
60000x60000) against checking and passing through a good 640x480 JPEG; and shrinking a 4096x3072
JPEG to 640 wide with reduce-on-decode (draft) against a full-size decode (the old way).
Figures as JSON lines, then a table.
usage: scripts/run.sh python bench/bench_frame_forwarder.py [--triggers N]
"""

from __future__ import annotations

import argparse
import array
import io
import json
import os
import statistics
import struct
import subprocess
import sys
import threading
import time
import uuid
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
FORWARDER = ROOT / "install" / "by_your_command" / "lib" / "by_your_command" / "frame_forwarder"
WIDTH, HEIGHT = 640, 480


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q / 100 * (len(ordered) - 1))))]


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    print(
        json.dumps(
            {"bench": "frame_forwarder", "figure": figure, "value": round(value, 4), "unit": unit, **extra}
        )
    )


def timed_ms(action: Callable[[], object], runs: int) -> list[float]:
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        action()
        times.append((time.perf_counter() - start) * 1000)
    return times


def encode_baseline(frame_bytes: bytes, runs: int) -> list[float]:
    from by_your_command.bridge.frames import FrameForwarderParams
    from by_your_command.bridge.imaging import ImageLimits, RawImage, encode_raw

    params = FrameForwarderParams()
    limits = ImageLimits(params.max_input_pixels, params.max_input_bytes)
    image = RawImage(WIDTH, HEIGHT, "rgb8", WIDTH * 3, frame_bytes)
    return timed_ms(lambda: encode_raw(image, WIDTH, 80, limits), runs)


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def hostile_frames(runs: int) -> list[tuple[str, list[float]]]:
    """In-process costs: refusing bombs vs a good frame; reduce-on-decode vs a full decode."""
    import numpy as np
    from PIL import Image as PilImage

    from by_your_command.bridge.frames import FrameForwarderParams
    from by_your_command.bridge.imaging import ImageError, ImageLimits, fit_compressed

    params = FrameForwarderParams()
    limits = ImageLimits(params.max_input_pixels, params.max_input_bytes)

    def jpeg_of(width: int, height: int) -> bytes:
        gradient = np.add.outer(np.arange(height), np.arange(width)) % 256
        out = io.BytesIO()
        PilImage.fromarray(gradient.astype(np.uint8), "L").convert("RGB").save(out, "JPEG", quality=85)
        return out.getvalue()

    good = jpeg_of(WIDTH, HEIGHT)
    big = jpeg_of(4096, 3072)
    forged_jpeg = bytearray(jpeg_of(16, 16))
    sof = forged_jpeg.find(b"\xff\xc0")
    forged_jpeg[sof + 5 : sof + 9] = struct.pack(">HH", 60000, 60000)
    forged_png = (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0))
        + _png_chunk(b"IDAT", zlib.compress(b"\0" * 64))
        + _png_chunk(b"IEND", b"")
    )

    def refused(data: bytes) -> None:
        try:
            fit_compressed(data, WIDTH, 80, limits)
        except ImageError:
            return
        raise AssertionError("a bomb was not refused")

    def full_decode_shrink() -> None:  # before reduce-on-decode: decode 4096x3072, then resize
        with PilImage.open(io.BytesIO(big)) as image:
            image.convert("RGB").resize((WIDTH, 480), PilImage.Resampling.BILINEAR).save(io.BytesIO(), "JPEG")

    return [
        (
            "good 640x480 JPEG checked, passed through",
            timed_ms(lambda: fit_compressed(good, WIDTH, 80, limits), runs),
        ),
        ("PNG bomb 60000x60000 refused", timed_ms(lambda: refused(forged_png), runs)),
        ("JPEG bomb 60000x60000 refused", timed_ms(lambda: refused(bytes(forged_jpeg)), runs)),
        ("4096x3072 JPEG → 640, full decode (old)", timed_ms(full_decode_shrink, max(3, runs // 10))),
        (
            "4096x3072 JPEG → 640, reduce on decode",
            timed_ms(lambda: fit_compressed(big, WIDTH, 80, limits), max(3, runs // 10)),
        ),
    ]


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--triggers", type=int, default=100)
    args = parser.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

    import numpy as np
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import CompressedImage, Image
    from std_msgs.msg import Bool

    from by_your_command.nodes import _qos

    rng = np.random.default_rng(1)
    # a smooth gradient plus noise: JPEG cost similar to a camera picture, not to a flat colour
    gradient = np.add.outer(np.arange(HEIGHT), np.arange(WIDTH)) % 256
    pixels = np.repeat(gradient[:, :, None], 3, axis=2) + rng.integers(0, 16, (HEIGHT, WIDTH, 3))
    frame_bytes = pixels.astype(np.uint8).tobytes()
    encode_ms = encode_baseline(frame_bytes, args.triggers)
    hostile = hostile_frames(args.triggers)

    namespace = f"/bench_{uuid.uuid4().hex[:8]}"
    process = subprocess.Popen(
        [
            str(FORWARDER),
            "--ros-args",
            "-r",
            f"__ns:={namespace}",
            "-p",
            "max_video_fps:=0.0",
            "-p",
            "image_reliable:=true",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("bench_frames", namespace=namespace, context=context)
    arrived = threading.Event()
    arrival = [0.0]
    trigger_seen: list[float] = []

    def on_forwarded(_msg: Any) -> None:
        arrival[0] = time.monotonic()
        arrived.set()

    def on_trigger(msg: Any) -> None:
        trigger_seen.append(time.monotonic())

    node.create_subscription(CompressedImage, "camera_forwarded", on_forwarded, _qos.RELIABLE)
    node.create_subscription(Bool, "voice_activity", on_trigger, _qos.RELIABLE)
    camera = node.create_publisher(Image, "camera/image_raw", _qos.RELIABLE)
    voice = node.create_publisher(Bool, "voice_activity", _qos.RELIABLE)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    threading.Thread(target=executor.spin, daemon=True).start()
    latencies: list[float] = []
    trigger_dds: list[float] = []
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not (
            camera.get_subscription_count()
            and voice.get_subscription_count() >= 2
            and node.count_publishers(f"{namespace}/camera_forwarded")
        ):
            time.sleep(0.05)
        msg = Image(width=WIDTH, height=HEIGHT, encoding="rgb8", step=WIDTH * 3)
        msg.data = array.array("B", frame_bytes)
        attempts = 0
        while len(latencies) < args.triggers and attempts < args.triggers * 2:
            attempts += 1
            msg.header.stamp.sec = attempts
            camera.publish(msg)
            time.sleep(0.05)  # let the frame reach the forwarder's cache (this is what we do not time)
            arrived.clear()
            trigger_seen.clear()
            start = time.monotonic()
            voice.publish(Bool(data=True))
            if arrived.wait(1.0):
                latencies.append((arrival[0] - start) * 1000)
                if trigger_seen:
                    trigger_dds.append((trigger_seen[0] - start) * 1000)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        process.terminate()
        try:
            process.wait(5)
        except subprocess.TimeoutExpired:
            process.kill()
    if not latencies:
        print("no forwarded frames: is the package built (scripts/bootstrap.sh)?", file=sys.stderr)
        return 1
    rows = [
        ("JPEG encode 640x480 (in-process)", encode_ms),
        ("trigger Bool over DDS", trigger_dds),
        ("trigger → forwarded frame", latencies),
    ]
    for name, values in rows:
        emit("latency_p50", statistics.median(values), "ms", path=name, n=len(values))
        emit("latency_p99", percentile(values, 99), "ms", path=name, n=len(values))
    emit("ratio_p50_trigger_vs_encode", statistics.median(latencies) / statistics.median(encode_ms), "x")
    for name, values in hostile:
        emit("cost_p50", statistics.median(values), "ms", path=name, n=len(values))
    medians = {name: statistics.median(values) for name, values in hostile}
    good = medians["good 640x480 JPEG checked, passed through"]
    emit("ratio_p50_png_bomb_vs_good_frame", medians["PNG bomb 60000x60000 refused"] / good, "x")
    emit("ratio_p50_jpeg_bomb_vs_good_frame", medians["JPEG bomb 60000x60000 refused"] / good, "x")
    emit(
        "ratio_p50_reduce_on_decode_vs_full_decode",
        medians["4096x3072 JPEG → 640, reduce on decode"]
        / medians["4096x3072 JPEG → 640, full decode (old)"],
        "x",
    )
    print()
    print(f"{'path':<44} {'p50 ms':>8} {'p99 ms':>8} {'n':>5}")
    for name, values in [*rows, *hostile]:
        print(f"{name:<44} {statistics.median(values):>8.3f} {percentile(values, 99):>8.3f} {len(values):>5}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
