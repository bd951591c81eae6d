"""The frame_forwarder node forwards a fresh, JPEG-encoded frame right after a voice trigger."""

from __future__ import annotations

import array
import io

import pytest
from byc_testing import INSTALL_LIB, running_process, wait_for
from PIL import Image as PilImage
from rclpy.node import Node
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Bool

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
        # camera yet when discovery says so on our side: publish until a trigger is answered.
        index = 0

        def triggered() -> bool:
            nonlocal index
            index += 1
            camera.publish(frame(index))
            voice.publish(Bool(data=True))
            return bool(forwarded)

        wait_for(triggered, timeout=20, interval=0.05, what="a forwarded frame")
        out = forwarded[0]
        assert out.format == "jpeg" and out.header.frame_id == "camera"
        assert 1 <= out.header.stamp.sec <= index
        image = PilImage.open(io.BytesIO(bytes(out.data)))
        assert image.size == (320, 180)
