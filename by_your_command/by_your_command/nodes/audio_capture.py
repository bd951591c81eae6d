"""audio_capture: PortAudio microphone -> `audio` (AudioChunk, mono, stamped with the capture time
of the first sample). `audio_capture --list-devices` prints the devices and exits.
Logic lives in audio/devices.py."""

from __future__ import annotations

import sys
import threading

from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk
from rclpy.node import Node

from by_your_command.audio.devices import (
    AudioDeviceError,
    CaptureConfig,
    CaptureMonitor,
    CaptureQueue,
    CaptureStream,
    format_devices,
    query_devices,
    select_device,
)
from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import STREAM

NS_PER_S = 1_000_000_000
FIRST_CALLBACK_WARN_S = 5.0


class AudioCaptureNode(Node):
    def __init__(self) -> None:
        super().__init__("audio_capture")
        self.config = declare_config(self, CaptureConfig)
        devices, default_input, default_output = query_devices()
        if self.config.list_devices:
            self.get_logger().info(
                "audio devices:\n" + format_devices(devices, default_input, default_output)
            )
        device = select_device(devices, self.config.device, "input", default_input)
        self.publisher = self.create_publisher(AudioChunk, "audio", STREAM)
        self.queue = CaptureQueue(self.config.queue_chunks)
        self.stream = CaptureStream(self.config, device, self.queue)
        self.monitor = CaptureMonitor(self.config, self.stream.channels, self.queue)
        self.get_logger().info(
            f"opened input device {device.index} '{device.name}' at {self.config.sample_rate} Hz, "
            f"{self.stream.channels} ch, chunk {self.config.chunk}; waiting for the first callback"
        )
        self._running = True
        self._thread = threading.Thread(target=self._pump, name="capture", daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        logger = self.get_logger()
        if not self.queue.first_callback.wait(FIRST_CALLBACK_WARN_S):
            logger.warning(f"no audio from the device after {FIRST_CALLBACK_WARN_S:.0f} s; still waiting")
        while self._running:
            chunk = self.queue.get(timeout=0.2)
            if chunk is None:
                continue
            mono, events = self.monitor.process(chunk)
            for event in events:
                (logger.warning if event.level == "warning" else logger.info)(event.text)
            msg = make_audio_chunk(mono, self.config.sample_rate, 1)
            msg.header.stamp = Time(sec=chunk.start_ns // NS_PER_S, nanosec=chunk.start_ns % NS_PER_S)
            try:
                self.publisher.publish(msg)
            except Exception as error:  # rclpy can raise under overload or at shutdown
                if self._running:
                    logger.error(f"publish failed: {error}", throttle_duration_sec=5.0)

    def destroy_node(self) -> None:
        self._running = False
        self._thread.join(timeout=2)
        self.stream.close()
        super().destroy_node()


def list_devices() -> int:
    devices, default_input, default_output = query_devices()
    print(format_devices(devices, default_input, default_output))
    return 0


def main(args: list[str] | None = None) -> None:
    argv = list(args if args is not None else sys.argv)
    if "--list-devices" in argv:
        raise SystemExit(list_devices())
    from by_your_command.nodes._runtime import run_node

    def make() -> Node:
        try:
            return AudioCaptureNode()
        except (AudioDeviceError, ValueError) as error:  # no device, or a bad parameter
            raise SystemExit(f"audio_capture: {error}") from None

    run_node(make, argv)


if __name__ == "__main__":
    main()
