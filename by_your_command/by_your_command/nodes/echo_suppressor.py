"""echo_suppressor: `audio` -> `audio_filtered`, with the mic gated (gate), echo-cancelled (aec)
or passed through (external). Logic lives in audio/echo.py."""

from __future__ import annotations

import sys
from pathlib import Path

from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk
from rclpy.node import Node
from std_msgs.msg import Bool

from by_your_command.audio import echo_memory
from by_your_command.audio.echo import Block, EchoConfig, EchoController, EchoMode
from by_your_command.audio.pcm import check_sample_rate, to_mono
from by_your_command.nodes._audio_msgs import make_audio_chunk, pcm_of
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import AUDIO_IN, LATCHED, STREAM

NS_PER_S = 1_000_000_000
STATS_PERIOD_S = 10.0


def _to_ns(stamp: Time) -> int:
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def _to_time(ns: int) -> Time:
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


class EchoSuppressorNode(Node):
    def __init__(self) -> None:
        super().__init__("echo_suppressor")
        self.config = declare_config(self, EchoConfig)
        self.sample_rate = self.config.sample_rate
        self.echo = EchoController(self.config)
        self.publisher = self.create_publisher(AudioChunk, "audio_filtered", STREAM)
        self.create_subscription(AudioChunk, "audio", self._on_audio, AUDIO_IN)
        self.create_subscription(Bool, "assistant_speaking", self._on_speaking, LATCHED)
        if self.echo.mode is EchoMode.AEC:
            self.create_subscription(AudioChunk, "audio_played", self._on_played, AUDIO_IN)
        self._reported: tuple[int, ...] = ()
        self.create_timer(STATS_PERIOD_S, self._report)
        self._memory: Path | None = None
        if self.echo.echo_path_shape is not None:
            self._memory = echo_memory.memory_file(
                self.config.aec_echo_memory, self.get_fully_qualified_name()
            )
        if self._memory is not None:
            self._log(echo_memory.restore(self.echo, self._memory))
        aec = (
            f" aec_engine={self.config.aec_engine} "
            f"aec_delay={self.echo.aec_delay_samples * 1000 / self.sample_rate:.1f}ms "
            f"echo_guard={self.config.echo_guard}"
            if self.echo.mode is EchoMode.AEC
            else ""
        )
        self.get_logger().info(
            f"echo control ready: mode={self.config.mode} rate={self.sample_rate} "
            f"gate_tail_ms={self.config.gate_tail_ms}{aec}"
        )

    def _now_ns(self) -> int:
        return int(self.get_clock().now().nanoseconds)

    def _on_speaking(self, msg: Bool) -> None:
        self.echo.set_assistant_speaking(bool(msg.data), self._now_ns())
        self._publish(self.echo.drain())
        if not msg.data:
            self._remember()

    def _remember(self) -> None:
        """Keep the echo path learned so far (at the end of each reply and at shutdown)."""
        if self._memory is not None:
            outcome = echo_memory.keep(self.echo, self._memory)
            if outcome is not None and not outcome.ok:
                self._log(outcome)

    def _log(self, outcome: echo_memory.Outcome) -> None:
        if outcome.ok:
            self.get_logger().info(outcome.message)
        else:
            self.get_logger().warning(outcome.message, throttle_duration_sec=60.0)

    def before_shutdown(self) -> None:
        self._remember()

    def _on_played(self, msg: AudioChunk) -> None:
        try:
            check_sample_rate(msg.sample_rate)
            self.echo.add_reference(pcm_of(msg), msg.sample_rate, msg.channels, _to_ns(msg.header.stamp))
        except ValueError as error:
            self.echo.stats.reference_rejected += 1
            self.get_logger().warning(
                f"bad audio_played chunk dropped: {error} ({self.echo.stats.reference_rejected} so far)",
                throttle_duration_sec=5.0,
            )
            return
        self._publish(self.echo.drain())

    def _on_audio(self, msg: AudioChunk) -> None:
        now = self._now_ns()
        start = _to_ns(msg.header.stamp) or now
        if self.echo.mode is not EchoMode.AEC:
            if self.echo.process(pcm_of(msg), start, now):
                self.publisher.publish(msg)  # forwarded unchanged: rate, channels and stamp kept
            return
        try:
            check_sample_rate(msg.sample_rate)
            blocks = self.echo.process(to_mono(pcm_of(msg), msg.channels), start, now, msg.sample_rate)
        except ValueError as error:
            self.echo.stats.blocks_rejected += 1
            self.get_logger().error(
                f"bad audio chunk dropped: {error} ({self.echo.stats.blocks_rejected} so far)",
                throttle_duration_sec=5.0,
            )
            return
        self._publish(blocks)

    def _publish(self, blocks: list[Block]) -> None:
        for block in blocks:
            self.publisher.publish(make_audio_chunk(block.pcm, self.sample_rate, 1, _to_time(block.start_ns)))

    def _report(self) -> None:
        stats = self.echo.stats
        current = (stats.blocks_in, stats.blocks_gated, stats.blocks_rejected, stats.reference_rejected)
        if current != self._reported:
            self._reported = current
            self.get_logger().info(
                f"audio blocks in={stats.blocks_in} out={stats.blocks_out} gated={stats.blocks_gated} "
                f"rejected={stats.blocks_rejected} reference_rejected={stats.reference_rejected} "
                f"aec_frames={stats.aec_frames} unreferenced={stats.aec_frames_unreferenced} "
                f"guard_muted={stats.guard_frames_muted} double_talk={stats.double_talk_frames} "
                f"path_changes={stats.path_changes} remembered_dropped={stats.remembered_dropped} "
                f"remembered_relearned={stats.remembered_relearned} "
                f"mic_resyncs={stats.mic_resyncs} "
                f"reference_restarts={stats.reference_restarts} "
                f"late_reference_samples={stats.reference_samples_late}"
            )


def main(args: list[str] | None = None) -> None:
    from by_your_command.nodes._runtime import run_node

    def make() -> Node:
        try:
            return EchoSuppressorNode()
        except ValueError as error:  # a bad parameter: say which, no traceback
            raise SystemExit(f"echo_suppressor: {error}") from None

    run_node(make, args if args is not None else sys.argv)


if __name__ == "__main__":
    main()
