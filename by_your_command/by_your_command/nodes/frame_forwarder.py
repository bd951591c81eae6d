"""frame_forwarder: send agents a fresh camera frame when it matters (docs/bridge.md, "Frame forwarding").

Thin node over bridge.frames.FrameForwarder (when) and bridge.imaging (JPEG, resize).
in:  <image_topic> (sensor_msgs/Image or CompressedImage), voice_activity, prompt_text, prompt_voice
out: camera_forwarded (sensor_msgs/CompressedImage, header of the camera frame)
"""

from __future__ import annotations

import array
from dataclasses import dataclass
from typing import Any

from by_your_command_msgs.msg import AudioDataUtterance
from rclpy.node import Node
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Bool, String

from by_your_command.bridge.frames import Forward, FrameForwarder, FrameForwarderParams
from by_your_command.bridge.imaging import ImageError, RawImage, encode_raw, fit_compressed
from by_your_command.nodes import _qos
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._runtime import run_node


@dataclass
class _Frame:
    msg: Any  # Image or CompressedImage, as received
    jpeg: tuple[str, bytes] | None = None  # encoded once, even if forwarded by two triggers


class FrameForwarderNode(Node):
    def __init__(self) -> None:
        super().__init__("frame_forwarder")
        self.params = declare_config(self, FrameForwarderParams)
        self.forwarder: FrameForwarder[_Frame] = FrameForwarder(self.params)
        self.encode_errors = 0
        self._output = self.create_publisher(CompressedImage, "camera_forwarded", _qos.RELIABLE)
        image_type = Image if self.params.image_transport == "raw" else CompressedImage
        # Best effort matches every camera; large raw frames may then be lost between processes,
        # so a reliable camera can be subscribed reliably.
        image_qos = _qos.RELIABLE if self.params.image_reliable else _qos.STREAM
        self.create_subscription(image_type, self.params.image_topic, self._on_image, image_qos)
        self.create_subscription(Bool, "voice_activity", self._on_voice_activity, _qos.RELIABLE)
        self.create_subscription(String, "prompt_text", self._on_text, _qos.RELIABLE)
        self.create_subscription(AudioDataUtterance, "prompt_voice", self._on_voice_chunk, _qos.RELIABLE)
        self.create_timer(30.0, self._log_stats)
        self.get_logger().info(
            f"frame_forwarder ready: {self.params.image_transport} frames from {self.params.image_topic}, "
            f"baseline {self.params.max_video_fps:g} fps"
        )

    def _on_image(self, msg: Any) -> None:
        self._send(self.forwarder.on_frame(_Frame(msg)))

    def _on_voice_activity(self, msg: Bool) -> None:
        self._send(self.forwarder.on_voice_activity(msg.data))

    def _on_text(self, _msg: String) -> None:
        self._send(self.forwarder.on_text())

    def _on_voice_chunk(self, msg: AudioDataUtterance) -> None:
        self._send(self.forwarder.on_voice_chunk(msg.chunk_sequence))

    def _send(self, forward: Forward[_Frame] | None) -> None:
        if forward is None:
            return
        frame = forward.frame
        try:
            if frame.jpeg is None:
                frame.jpeg = self._encode(frame.msg)
        except ImageError as error:
            self.encode_errors += 1
            self.get_logger().error(f"cannot forward a frame ({forward.reason}): {error}")
            return
        image_format, data = frame.jpeg
        out = CompressedImage(header=frame.msg.header, format=image_format)
        out.data = array.array("B", data)
        self._output.publish(out)

    def _encode(self, msg: Any) -> tuple[str, bytes]:
        width, quality = self.params.max_width, self.params.jpeg_quality
        if isinstance(msg, CompressedImage):
            return fit_compressed(bytes(msg.data), width, quality)
        raw = RawImage(
            msg.width, msg.height, msg.encoding, msg.step, memoryview(msg.data), bool(msg.is_bigendian)
        )
        return "jpeg", encode_raw(raw, width, quality)

    def _log_stats(self) -> None:
        stats = self.forwarder.stats
        self.get_logger().info(
            f"frames in {stats.frames_in}, forwarded {stats.forwarded}, stale triggers "
            f"{stats.stale_triggers}, encode errors {self.encode_errors}"
        )


def main(args: list[str] | None = None) -> None:
    run_node(FrameForwarderNode, args)


if __name__ == "__main__":
    main()
