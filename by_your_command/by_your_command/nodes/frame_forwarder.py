"""frame_forwarder: send agents a fresh camera frame when it matters (docs/bridge.md, "Frame forwarding").

Thin node over bridge.frames.FrameForwarder (when) and bridge.imaging (checks, JPEG, resize).
in:  <image_topic> (sensor_msgs/Image or CompressedImage), voice_activity, prompt_text, prompt_voice
out: camera_forwarded (sensor_msgs/CompressedImage, header of the camera frame)

Camera frames are untrusted: a frame is checked cheaply when it arrives (raw geometry, or the
compressed header's format and declared size) and a bad one is counted, logged (rate-limited) and
dropped, so it never displaces the last good frame. Decoding happens only for forwarded frames and
is bounded; a failure there is counted too. No callback exception can stop the node.
"""

from __future__ import annotations

import array
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from by_your_command_msgs.msg import AudioDataUtterance
from rclpy.node import Node
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Bool, String

from by_your_command.bridge.frames import ErrorTally, Forward, FrameForwarder, FrameForwarderParams
from by_your_command.bridge.imaging import (
    ImageError,
    ImageLimits,
    RawImage,
    check_data_length,
    check_raw,
    encode_raw,
    fit_compressed,
    probe_compressed,
)
from by_your_command.nodes import _qos
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._runtime import run_node


@dataclass
class _Frame:
    msg: Any  # Image or CompressedImage, as received
    raw: RawImage | None = None  # checked raw frame
    compressed: bytes | None = None  # checked compressed frame's bytes
    jpeg: tuple[str, bytes] | None = None  # encoded once, even if forwarded by two triggers


class FrameForwarderNode(Node):
    def __init__(self) -> None:
        super().__init__("frame_forwarder")
        self.params = declare_config(self, FrameForwarderParams)
        self.limits = ImageLimits(self.params.max_input_pixels, self.params.max_input_bytes)
        self.forwarder: FrameForwarder[_Frame] = FrameForwarder(self.params)
        self.errors = ErrorTally(self.params.error_log_interval_s)  # kind -> count, for every failure
        self._output = self.create_publisher(CompressedImage, "camera_forwarded", _qos.RELIABLE)
        image_type = Image if self.params.image_transport == "raw" else CompressedImage
        # Best effort matches every camera; large raw frames may then be lost between processes,
        # so a reliable camera can be subscribed reliably.
        image_qos = _qos.RELIABLE if self.params.image_reliable else _qos.STREAM
        self.create_subscription(image_type, self.params.image_topic, self._guard(self._on_image), image_qos)
        self.create_subscription(Bool, "voice_activity", self._guard(self._on_voice_activity), _qos.RELIABLE)
        self.create_subscription(String, "prompt_text", self._guard(self._on_text), _qos.RELIABLE)
        self.create_subscription(
            AudioDataUtterance, "prompt_voice", self._guard(self._on_voice_chunk), _qos.RELIABLE
        )
        self.create_timer(30.0, self._guard(self._log_stats))
        self.get_logger().info(
            f"frame_forwarder ready: {self.params.image_transport} frames from {self.params.image_topic}, "
            f"baseline {self.params.max_video_fps:g} fps"
        )

    def _guard(self, callback: Callable[..., None]) -> Callable[..., None]:
        """An exception escaping a callback would end the executor's spin, and with it the node."""

        def guarded(*args: Any) -> None:
            try:
                callback(*args)
            except Exception as error:  # a bug, not bad input: report it loudly and keep running
                self._error("internal", f"{getattr(callback, '__name__', 'callback')} failed: {error!r}")

        return guarded

    def _error(self, kind: str, message: str) -> None:
        if self.errors.record(kind):
            self.get_logger().error(
                f"{message} [{kind}: {self.errors.counts[kind]} so far; "
                f"{self.errors.unlogged} errors not logged since start]"
            )

    def _on_image(self, msg: Any) -> None:
        frame = self._admit(msg)
        if frame is not None:
            self._send(self.forwarder.on_frame(frame))

    def _admit(self, msg: Any) -> _Frame | None:
        """The frame when its header/geometry passes the checks; None (counted, logged) when not."""
        try:
            if isinstance(msg, CompressedImage):
                check_data_length(len(msg.data), self.limits)  # before copying it
                data = bytes(msg.data)
                probe_compressed(data, self.limits)
                return _Frame(msg, compressed=data)
            raw = RawImage(
                msg.width, msg.height, msg.encoding, msg.step, memoryview(msg.data), bool(msg.is_bigendian)
            )
            check_raw(raw, self.limits)
            return _Frame(msg, raw=raw)
        except ImageError as error:
            self._error(error.kind.value, f"rejected a camera frame: {error}")
            return None

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
                frame.jpeg = self._encode(frame)
        except ImageError as error:
            self._error(error.kind.value, f"cannot forward a frame ({forward.reason}): {error}")
            return
        image_format, data = frame.jpeg
        out = CompressedImage(header=frame.msg.header, format=image_format)
        out.data = array.array("B", data)
        self._output.publish(out)

    def _encode(self, frame: _Frame) -> tuple[str, bytes]:
        width, quality = self.params.max_width, self.params.jpeg_quality
        if frame.compressed is not None:
            return fit_compressed(frame.compressed, width, quality, self.limits)
        assert frame.raw is not None
        return "jpeg", encode_raw(frame.raw, width, quality, self.limits)

    def _log_stats(self) -> None:
        stats = self.forwarder.stats
        self.get_logger().info(
            f"frames in {stats.frames_in}, forwarded {stats.forwarded}, stale triggers "
            f"{stats.stale_triggers}, errors {self.errors.counts or 'none'}"
        )


def main(args: list[str] | None = None) -> None:
    run_node(FrameForwarderNode, args)


if __name__ == "__main__":
    main()
