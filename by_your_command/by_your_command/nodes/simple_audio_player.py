"""simple_audio_player: `response_voice` -> speaker (or a WAV sink), honoring `interruption_signal`.

Publishes `assistant_speaking` (latched), `playback_status` (what was actually played, per
response) and `audio_played` (each block as played, stamped with its play time: the AEC reference).
Logic lives in audio/player.py and audio/sinks.py.
"""

from __future__ import annotations

import sys
import threading

from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk, PlaybackStatus
from rclpy.node import Node
from std_msgs.msg import Bool

from by_your_command.audio.devices import AudioDeviceError, query_devices, select_device
from by_your_command.audio.player import (
    PlaybackEngine,
    PlaybackState,
    PlayBlock,
    PlayerConfig,
    PlayerLoop,
)
from by_your_command.audio.sinks import AudioSink, DeviceSink, WavSink
from by_your_command.nodes._audio_msgs import make_audio_chunk, pcm_of
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

NS_PER_S = 1_000_000_000


def _to_time(ns: int) -> Time:
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


def open_sink(config: PlayerConfig) -> AudioSink:
    if config.sink == "wav":
        return WavSink(config.wav_path, config.sample_rate, config.realtime)
    devices, _, default_output = query_devices()
    device = select_device(devices, config.device, "output", default_output)
    return DeviceSink(device.index, config.sample_rate, config.block_samples)


class SimpleAudioPlayerNode(Node):
    def __init__(self) -> None:
        super().__init__("simple_audio_player")
        self.config = declare_config(self, PlayerConfig)
        self.engine = PlaybackEngine(
            self.config.sample_rate,
            self.config.block_samples,
            self.config.max_queue_ms * self.config.sample_rate // 1000,
        )
        self.sink = open_sink(self.config)
        self.speaking_pub = self.create_publisher(Bool, "assistant_speaking", LATCHED)
        self.status_pub = self.create_publisher(PlaybackStatus, "playback_status", RELIABLE)
        self.played_pub = self.create_publisher(AudioChunk, "audio_played", STREAM)
        self.loop = PlayerLoop(self.engine, self.sink, self._on_played, self._publish_state)
        # RELIABLE: agents send replies in bursts faster than real time; best effort would drop them.
        self.create_subscription(AudioChunk, "response_voice", self._on_voice, RELIABLE)
        self.create_subscription(Bool, "interruption_signal", self._on_interruption, RELIABLE)
        self.create_timer(1.0 / self.config.status_rate_hz, self._on_status_timer)
        self._last_status: PlaybackState | None = None
        self._state_lock = threading.Lock()
        self._speaking_sent: bool | None = None
        self._publish_state()
        self.loop.start()
        self.get_logger().info(
            f"player ready: sink={self.config.sink} rate={self.config.sample_rate} "
            f"block_ms={self.config.block_ms}"
            + (f" wav_path={self.config.wav_path}" if self.config.wav_path else "")
        )

    def _now_ns(self) -> int:
        return int(self.get_clock().now().nanoseconds)

    def _on_voice(self, msg: AudioChunk) -> None:
        try:
            self.engine.enqueue(msg.stream_id, pcm_of(msg), int(msg.sample_rate), int(msg.channels))
        except ValueError as error:
            self.get_logger().error(
                f"response_voice chunk dropped: {error} ({self.engine.stats.chunks_rejected} so far)",
                throttle_duration_sec=5.0,
            )
            return
        self.loop.wake()

    def _on_interruption(self, msg: Bool) -> None:
        if not msg.data:
            return
        busy = self.loop.interrupt()
        self.get_logger().info("interrupted: playback flushed" if busy else "interruption while idle")
        self._publish_state()

    def _on_played(self, block: PlayBlock, start_ns: int) -> None:
        self.played_pub.publish(
            make_audio_chunk(block.pcm, self.config.sample_rate, 1, _to_time(start_ns), block.stream_id)
        )

    def _on_status_timer(self) -> None:
        state = self.engine.status(self._now_ns())
        if state.speaking or self._last_status != state:
            self._publish_state()

    def _publish_state(self) -> None:
        """Called from the player thread and from callbacks: publish speaking and status now."""
        with self._state_lock:
            now = self._now_ns()
            state = self.engine.status(now)
            if state.speaking != self._speaking_sent:
                self._speaking_sent = state.speaking
                self.speaking_pub.publish(Bool(data=state.speaking))
            self._last_status = state
            self.status_pub.publish(self._status_msg(state, now))

    @staticmethod
    def _status_msg(state: PlaybackState, now: int) -> PlaybackStatus:
        msg = PlaybackStatus(
            stream_id=state.stream_id,
            played_ms=state.played_ms,
            queued_ms=state.queued_ms,
            speaking=state.speaking,
            finished=state.finished,
            interrupted=state.interrupted,
        )
        msg.header.stamp = _to_time(now)
        return msg

    def destroy_node(self) -> None:
        self.loop.stop()
        stats = self.engine.stats
        self.get_logger().info(
            f"player stopped: chunks={stats.chunks} blocks={stats.blocks_played} "
            f"interruptions={stats.interruptions} dropped_late={stats.chunks_dropped_interrupted} "
            f"dropped_overflow_samples={stats.samples_dropped_overflow} rejected={stats.chunks_rejected}"
        )
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    from by_your_command.nodes._runtime import run_node

    def make() -> Node:
        try:
            return SimpleAudioPlayerNode()
        except AudioDeviceError as error:
            raise SystemExit(
                f"simple_audio_player: {error} (without a sound card: -p sink:=wav -p wav_path:=FILE)"
            ) from None
        except ValueError as error:  # a bad parameter: say which, no traceback
            raise SystemExit(f"simple_audio_player: {error}") from None

    run_node(make, args if args is not None else sys.argv)


if __name__ == "__main__":
    main()
