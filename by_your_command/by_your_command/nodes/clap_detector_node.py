"""clap_detector_node: audio -> wake_cmd (True) on a double clap. Logic lives in audio/clap.py."""

from __future__ import annotations

import sys
import time

from by_your_command_msgs.msg import AudioChunk
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Bool

from by_your_command.audio.clap import ClapConfig, ClapDetector, DoubleClap
from by_your_command.audio.pcm import resample, to_mono
from by_your_command.nodes._audio_msgs import pcm_of
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import RELIABLE, STREAM

STATS_PERIOD_S = 10.0
# A short timer keeps the executor's wait short, so a SIGTERM is handled promptly.
HOUSEKEEPING_PERIOD_S = 0.25


class ClapDetectorNode(Node):
    def __init__(self) -> None:
        super().__init__("clap_detector_node")
        self.config = declare_config(self, ClapConfig)
        self.detector = ClapDetector(self.config)
        self.enabled = self.config.enabled
        self.wake_pub = self.create_publisher(Bool, "wake_cmd", RELIABLE)
        self.create_subscription(AudioChunk, "audio", self._on_audio, STREAM)
        self.add_on_set_parameters_callback(self._on_parameters)
        self.blocks_rejected = 0
        self._reported = (0, 0, 0)
        self._last_report = time.monotonic()
        self.create_timer(HOUSEKEEPING_PERIOD_S, self._housekeeping)
        self.get_logger().info(f"clap detector ready (enabled={self.enabled})")

    def _on_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        # `enabled` can be flipped at run time (e.g. while the robot itself makes noise); the
        # thresholds are read once, so changing them is refused rather than silently ignored.
        fixed = [p.name for p in parameters if p.name != "enabled"]
        if fixed:
            return SetParametersResult(successful=False, reason=f"restart the node to change {fixed}")
        for parameter in parameters:
            self.enabled = bool(parameter.value)
            self.get_logger().info(f"clap detection enabled={self.enabled}")
        return SetParametersResult(successful=True)

    def _housekeeping(self) -> None:
        now = time.monotonic()
        if now - self._last_report < STATS_PERIOD_S:
            return
        self._last_report = now
        current = (self.detector.claps, self.detector.double_claps, self.blocks_rejected)
        if current != self._reported:
            self._reported = current
            self.get_logger().info(
                f"claps={current[0]} double_claps={current[1]} rejected_blocks={current[2]}"
            )

    def _on_audio(self, msg: AudioChunk) -> None:
        if not self.enabled:
            return
        try:
            pcm = to_mono(pcm_of(msg), int(msg.channels))
            if msg.sample_rate != self.config.sample_rate:
                pcm = resample(pcm, int(msg.sample_rate), self.config.sample_rate)
        except ValueError as error:
            self.blocks_rejected += 1
            self.get_logger().error(
                f"bad audio chunk dropped ({self.blocks_rejected} so far): {error}", throttle_duration_sec=5.0
            )
            return
        for event in self.detector.process(pcm):
            if isinstance(event, DoubleClap):
                gap_ms = (event.second.time_s - event.first.time_s) * 1000
                self.get_logger().info(f"double clap ({gap_ms:.0f} ms apart): wake")
                try:
                    self.wake_pub.publish(Bool(data=True))
                except Exception as error:  # rclpy raises RCLError under overload
                    self.get_logger().error(f"wake_cmd publish failed: {error}")


def main(args: list[str] | None = None) -> None:
    from by_your_command.nodes._runtime import run_node

    run_node(ClapDetectorNode, args if args is not None else sys.argv)


if __name__ == "__main__":
    main()
