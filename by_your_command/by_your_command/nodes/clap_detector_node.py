"""clap_detector_node: audio -> wake_cmd (True) on a double clap. Logic lives in audio/clap*.py.

A double clap only wakes: while the VAD's latched `attention_state` says "awake", the node does not
subscribe to `audio` at all (an audio subscription costs ~1.5 % of a core in rclpy even when the
detector has nothing to do). Without that topic (no VAD) it always listens."""

from __future__ import annotations

import sys
import time

from by_your_command_msgs.msg import AudioChunk
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.subscription import Subscription
from std_msgs.msg import Bool, String

from by_your_command.audio.clap import ClapConfig, ClapDetector, DoubleClap
from by_your_command.audio.pcm import StreamResampler, to_mono
from by_your_command.nodes._audio_msgs import pcm_of
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import AUDIO_IN, LATCHED, RELIABLE

STATS_PERIOD_S = 10.0
HOUSEKEEPING_PERIOD_S = 1.0  # only the stats line: each executor wake-up costs (docs/performance.md)


class ClapDetectorNode(Node):
    def __init__(self) -> None:
        super().__init__("clap_detector_node")
        self.config = declare_config(self, ClapConfig)
        self.detector = ClapDetector(self.config)
        self.enabled = self.config.enabled
        self.wake_pub = self.create_publisher(Bool, "wake_cmd", RELIABLE)
        self._audio_sub: Subscription | None = None
        self._listen(True)
        self.create_subscription(String, "attention_state", self._on_attention, LATCHED)
        self.add_on_set_parameters_callback(self._on_parameters)
        self.blocks_rejected = 0
        self.detector_errors = 0
        self._resampler: StreamResampler | None = None  # for input not at config.sample_rate
        self._reported: tuple[object, ...] = ()
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
            enabled = bool(parameter.value)
            if enabled and not self.enabled:
                # The audio skipped while disabled is a gap: never pair a clap across it.
                self.detector.reset()
                self._resampler = None
            self.enabled = enabled
            self.get_logger().info(f"clap detection enabled={self.enabled}")
        return SetParametersResult(successful=True)

    def _on_attention(self, msg: String) -> None:
        self._listen(msg.data != "awake")  # asleep or muted (unknown values too): a clap may wake

    def _listen(self, wanted: bool) -> None:
        if wanted and self._audio_sub is None:
            # The audio missed while not listening is a gap: never pair a clap across it.
            self.detector.reset()
            self._resampler = None
            self._audio_sub = self.create_subscription(AudioChunk, "audio", self._on_audio, AUDIO_IN)
            self.get_logger().info("listening for a double clap")
        elif not wanted and self._audio_sub is not None:
            self.destroy_subscription(self._audio_sub)
            self._audio_sub = None
            self.get_logger().info("the robot is awake: not listening for claps")

    def _housekeeping(self) -> None:
        now = time.monotonic()
        if now - self._last_report < STATS_PERIOD_S:
            return
        self._last_report = now
        d = self.detector
        current = (
            d.onsets,
            d.claps,
            d.double_claps,
            d.echoes,
            d.rhythms,
            tuple(sorted(d.rejected.items())),
            self.blocks_rejected,
            self.detector_errors,
        )
        if current != self._reported:
            self._reported = current
            self.get_logger().info(
                f"onsets={d.onsets} claps={d.claps} double_claps={d.double_claps} echoes={d.echoes} "
                f"rhythms={d.rhythms} not_claps={dict(d.rejected)} bad_blocks={self.blocks_rejected} "
                f"detector_errors={self.detector_errors}"
            )

    def _on_audio(self, msg: AudioChunk) -> None:
        if not self.enabled:
            return
        try:
            pcm = to_mono(pcm_of(msg), int(msg.channels))
            rate = int(msg.sample_rate)
            if rate != self.config.sample_rate:
                if self._resampler is None or self._resampler.from_rate != rate:
                    # A new rate is a new stream; the resampler checks the rate is plausible.
                    self._resampler = StreamResampler(rate, self.config.sample_rate)
                    self.get_logger().warning(
                        f"audio at {rate} Hz: resampling to {self.config.sample_rate} Hz"
                    )
                pcm = self._resampler.push(pcm)
        except ValueError as error:
            self.blocks_rejected += 1
            self.get_logger().error(
                f"bad audio chunk dropped ({self.blocks_rejected} so far): {error}", throttle_duration_sec=5.0
            )
            return
        try:
            events = self.detector.process(pcm)
        except Exception as error:  # a detector bug must not kill the node unseen: log, count, restart
            self.detector_errors += 1
            self.get_logger().error(
                f"clap detector failed ({self.detector_errors} so far), restarting it: {error!r}"
            )
            self.detector.reset()
            return
        for event in events:
            if isinstance(event, DoubleClap):
                self.get_logger().info(f"double clap ({event.gap_ms:.0f} ms apart): wake")
                try:
                    self.wake_pub.publish(Bool(data=True))
                except Exception as error:  # rclpy raises RCLError under overload
                    self.get_logger().error(f"wake_cmd publish failed: {error}")


def main(args: list[str] | None = None) -> None:
    from by_your_command.nodes._runtime import run_node

    run_node(ClapDetectorNode, args if args is not None else sys.argv)


if __name__ == "__main__":
    main()
