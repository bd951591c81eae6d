"""The frame_forwarder node forwards a fresh, JPEG-encoded frame right after a voice trigger, and
survives hostile frames (decompression bombs, garbage, inconsistent raw geometry)."""

from __future__ import annotations

import array
import io
import random
import struct
import zlib
from collections.abc import Callable
from typing import Any

import pytest
import rclpy
from byc_testing import INSTALL_LIB, running_process, wait_for
from PIL import Image as PilImage
from rclpy.node import Node
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Bool, String

from by_your_command.nodes import _qos

pytestmark = [pytest.mark.ros, pytest.mark.timeout(60)]


def frame(index: int, width: int = 1280, height: int = 720) -> Image:
    msg = Image(width=width, height=height, encoding="rgb8", step=width * 3)
    msg.header.stamp.sec = index
    msg.header.frame_id = "camera"
    msg.data = array.array("B", bytes([index % 256]) * (width * height * 3))
    return msg


def test_voice_trigger_forwards_the_latest_frame(ros_namespace: str, graph_node: Node) -> None:
    node = graph_node
    forwarded: list[CompressedImage] = []
    node.create_subscription(CompressedImage, "camera_forwarded", forwarded.append, _qos.RELIABLE)
    camera = node.create_publisher(Image, "camera/image_raw", _qos.RELIABLE)
    voice = node.create_publisher(Bool, "voice_activity", _qos.RELIABLE)
    args = [
        str(INSTALL_LIB / "frame_forwarder"),
        "--ros-args",
        "-r",
        f"__ns:={ros_namespace}",
        "-p",
        "max_video_fps:=0.0",
        "-p",
        "max_width:=320",
        # Reliable frames and a long wait: a trigger that overtakes its frame (no ordering across
        # topics) is answered when the frame lands. Best-effort 2.7 MB frames are each lost whole
        # when one fragment is dropped, which a loaded machine does for seconds at a time.
        "-p",
        "image_reliable:=true",
        "-p",
        "trigger_wait_ms:=10000",
    ]
    with running_process(args):
        wait_for(
            lambda: (
                camera.get_subscription_count()
                and voice.get_subscription_count()
                and node.count_publishers(f"{ros_namespace}/camera_forwarded")
            ),
            timeout=20,
            what="discovery",
        )
        # Baseline is off: only the trigger forwards. The forwarder may not have matched the
        # camera yet when discovery says so on our side (frames published before are not
        # delivered): publish until a trigger is answered.
        index = 0

        def triggered() -> bool:
            nonlocal index
            index += 1
            camera.publish(frame(index))
            voice.publish(Bool(data=True))
            return bool(forwarded)

        wait_for(triggered, timeout=30, interval=0.5, what="a forwarded frame")
        out = forwarded[0]
        assert out.format == "jpeg" and out.header.frame_id == "camera"
        assert 1 <= out.header.stamp.sec <= index
        image = PilImage.open(io.BytesIO(bytes(out.data)))
        assert image.size == (320, 180)


def _encoded(image: PilImage.Image, image_format: str) -> bytes:
    out = io.BytesIO()
    image.save(out, format=image_format)
    return out.getvalue()


def _forged_jpeg(width: int, height: int) -> bytes:
    data = bytearray(_encoded(PilImage.new("RGB", (16, 16), "red"), "JPEG"))
    sof = data.find(b"\xff\xc0")
    data[sof + 5 : sof + 9] = struct.pack(">HH", height, width)
    return bytes(data)


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def _forged_png(width: int, height: int) -> bytes:
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", header)
        + _png_chunk(b"IDAT", zlib.compress(b"\0" * 64))
        + _png_chunk(b"IEND", b"")
    )


def compressed(stamp: int, data: bytes) -> CompressedImage:
    msg = CompressedImage(format="jpeg")
    msg.header.stamp.sec = stamp
    msg.data = array.array("B", data)
    return msg


def raw(stamp: int, width: int, height: int, encoding: str, step: int, size: int) -> Image:
    msg = Image(width=width, height=height, encoding=encoding, step=step)
    msg.header.stamp.sec = stamp
    msg.data = array.array("B", bytes(size))
    return msg


GOOD_JPEG = _encoded(PilImage.new("RGB", (640, 360), "green"), "JPEG")
_NOISY_JPEG = _encoded(PilImage.effect_noise((320, 240), 60).convert("RGB"), "JPEG")
TRUNCATED_JPEG = _NOISY_JPEG[: len(_NOISY_JPEG) // 2]
# Stamps: good frames 1 and 100+, bad frames 1000+, so a forwarded bad frame would be visible.
BAD_COMPRESSED = {
    "png bomb 60000x60000": _forged_png(60000, 60000),
    "jpeg bomb 60000x60000": _forged_jpeg(60000, 60000),
    "random bytes": bytes(random.Random(7).randrange(256) for _ in range(4096)),
    "truncated jpeg": TRUNCATED_JPEG,  # the header is fine: fails only when decoded for forwarding
}
BAD_RAW = {
    "data longer than step x height": (8, 8, "rgb8", 24, 24 * 8 + 100),
    "data shorter than step x height": (8, 8, "rgb8", 24, 10),
    "absurd declared size": (60000, 60000, "rgb8", 180000, 1000),
    "step shorter than a row": (8, 8, "rgb8", 8, 64),
    "unknown encoding": (8, 8, "yuv422", 16, 128),
}


class ForwarderHarness:
    """A frame_forwarder process and the test's camera, trigger and output ends of the graph."""

    def __init__(self, node: Node, namespace: str, image_type: type) -> None:
        self.node = node
        self.namespace = namespace
        self.forwarded: list[CompressedImage] = []
        node.create_subscription(CompressedImage, "camera_forwarded", self.forwarded.append, _qos.RELIABLE)
        self.camera = node.create_publisher(image_type, "camera/image_raw", _qos.RELIABLE)
        self.voice = node.create_publisher(Bool, "voice_activity", _qos.RELIABLE)

    def wait_discovered(self) -> None:
        wait_for(
            lambda: (
                self.camera.get_subscription_count()
                and self.voice.get_subscription_count()
                and self.node.count_publishers(f"{self.namespace}/camera_forwarded")
            ),
            timeout=20,
            what="discovery",
        )

    def stamps(self) -> list[int]:
        return [msg.header.stamp.sec for msg in list(self.forwarded)]

    def first_frame(self, make_good: Callable[[int], Any]) -> None:
        # The forwarder may not have matched the camera yet when discovery says so on our side:
        # publish until a trigger is answered.
        def answered() -> bool:
            self.camera.publish(make_good(1))
            self.voice.publish(Bool(data=True))
            return bool(self.forwarded)

        wait_for(answered, timeout=20, interval=0.1, what="a first forwarded frame")

    def bad_then_good(self, bad: Any, good: Any) -> None:
        # A trigger right after the bad frame makes the forwarder try it, as a real turn would.
        self.camera.publish(bad)
        self.voice.publish(Bool(data=True))
        self.camera.publish(good)
        stamp = good.header.stamp.sec

        def arrived() -> bool:
            self.voice.publish(Bool(data=True))  # a trigger spent on the bad frame needs another
            return stamp in self.stamps()

        wait_for(arrived, timeout=20, interval=0.1, what=f"good frame {stamp} forwarded")


def _forwarder_args(namespace: str, transport: str) -> list[str]:
    return [
        str(INSTALL_LIB / "frame_forwarder"),
        "--ros-args",
        "-r",
        f"__ns:={namespace}",
        "-p",
        f"image_transport:={transport}",
        "-p",
        "image_reliable:=true",
        "-p",
        "max_video_fps:=0.0",
        "-p",
        "trigger_wait_ms:=10000",
        "-p",
        "error_log_interval_s:=0.0",
    ]


def test_compressed_bombs_and_garbage_are_counted_and_good_frames_keep_flowing(
    ros_namespace: str, graph_node: Node
) -> None:
    harness = ForwarderHarness(graph_node, ros_namespace, CompressedImage)
    with running_process(_forwarder_args(ros_namespace, "compressed")) as process:
        harness.wait_discovered()
        harness.first_frame(lambda stamp: compressed(stamp, GOOD_JPEG))
        for offset, name in enumerate(sorted(BAD_COMPRESSED)):
            harness.bad_then_good(
                compressed(1000 + offset, BAD_COMPRESSED[name]), compressed(100 + offset, GOOD_JPEG)
            )
            assert process.poll() is None, f"frame_forwarder died on {name}"
    output = process.stdout.read() if process.stdout else ""
    assert all(sec < 1000 for sec in harness.stamps()), harness.stamps()  # no bad frame went out
    assert all(bytes(msg.data) == GOOD_JPEG for msg in harness.forwarded)
    assert output.count("rejected a camera frame") == 3, output  # bombs and garbage: at arrival
    assert output.count("[too_large: ") == 2 and "not a JPEG or PNG" in output, output
    assert "cannot forward a frame" in output and "truncated" in output, output  # at decode time


def test_inconsistent_raw_frames_are_counted_and_good_frames_keep_flowing(
    ros_namespace: str, graph_node: Node
) -> None:
    harness = ForwarderHarness(graph_node, ros_namespace, Image)
    with running_process(_forwarder_args(ros_namespace, "raw")) as process:
        harness.wait_discovered()
        harness.first_frame(lambda stamp: frame(stamp, 64, 48))
        for offset, name in enumerate(sorted(BAD_RAW)):
            harness.bad_then_good(raw(1000 + offset, *BAD_RAW[name]), frame(100 + offset, 64, 48))
            assert process.poll() is None, f"frame_forwarder died on {name}"
    output = process.stdout.read() if process.stdout else ""
    assert all(sec < 1000 for sec in harness.stamps()), harness.stamps()
    assert output.count("rejected a camera frame") == len(BAD_RAW), output
    for kind in ("geometry", "too_large", "encoding"):
        assert f"[{kind}: " in output, output


def test_an_exception_in_a_callback_is_counted_and_the_node_keeps_working(ros_namespace: str) -> None:
    from by_your_command.nodes.frame_forwarder import FrameForwarderNode

    rclpy.init(args=["--ros-args", "-r", f"__ns:={ros_namespace}", "-p", "max_video_fps:=0.0"])
    node = None
    try:
        node = FrameForwarderNode()
        callbacks = {sub.topic_name.rsplit("/", 1)[-1]: sub.callback for sub in node.subscriptions}
        healthy_on_text = node.forwarder.on_text

        def broken() -> None:
            raise RuntimeError("a bug in the forwarding policy")

        node.forwarder.on_text = broken  # type: ignore[method-assign]
        callbacks["prompt_text"](String(data="hello"))  # would end the executor's spin unguarded
        assert node.errors.counts == {"internal": 1}
        node.forwarder.on_text = healthy_on_text  # type: ignore[method-assign]
        callbacks["image_raw"](frame(1, 64, 48))
        callbacks["prompt_text"](String(data="hello"))
        assert node.forwarder.stats.forwarded == {"text": 1}
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
