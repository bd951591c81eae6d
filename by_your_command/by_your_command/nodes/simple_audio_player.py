"""simple_audio_player: `response_voice` -> speaker (or a WAV sink), honoring `interruption_signal`
(cut, or pause and resume: an agent pauses a reply while it judges speech over it).

Publishes `assistant_speaking` (latched), `playback_status` (what was actually played, per
response) and `audio_played` (each block as played, stamped with its play time: the AEC reference).
Logic lives in audio/player.py and audio/sinks.py; this node only adapts messages and guards
every callback and publish (a failure is logged and counted, never kills playback).
"""

from __future__ import annotations

import sys
import threading
from typing import Any

from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk, Interruption, PlaybackStatus
from rclpy.node import Node
from rclpy.publisher import Publisher
from std_msgs.msg import Bool

from by_your_command.audio.devices import AudioDeviceError, query_devices, select_device
from by_your_command.audio.player import (
    MAX_STREAM_ID_CHARS,
    ChunkRejected,
    Cut,
    CutOutcome,
    PlaybackEngine,
    PlaybackState,
    PlayBlock,
    PlayerConfig,
    PlayerLoop,
    VoiceChunk,
)
from by_your_command.audio.sinks import AudioSink, DeviceSink, WavSink
from by_your_command.nodes._audio_msgs import make_audio_chunk, pcm_of
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

NS_PER_S = 1_000_000_000
LOG_EVERY_S = 5.0  # rate limit for repeated error lines


def _to_time(ns: int) -> Time:
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


def _stamp_ns(stamp: Time) -> int:
    """A header stamp in ns; 0 (unstamped) for zero or negative stamps."""
    return max(int(stamp.sec) * NS_PER_S + int(stamp.nanosec), 0)


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
            self.config.max_chunk_ms,
        )
        self.sink = open_sink(self.config)
        self.speaking_pub = self.create_publisher(Bool, "assistant_speaking", LATCHED)
        self.status_pub = self.create_publisher(PlaybackStatus, "playback_status", RELIABLE)
        self.played_pub = self.create_publisher(AudioChunk, "audio_played", STREAM)
        self.callback_errors = 0
        self.publish_errors = 0
        self.interruptions_rejected = 0
        self._last_status: PlaybackState | None = None
        self._state_lock = threading.Lock()
        self._speaking_sent: bool | None = None
        self._shut_down = False
        self.loop = PlayerLoop(
            self.engine,
            self.sink,
            self._on_played,
            self._publish_state,
            on_error=self._on_loop_error,
            max_pause_ns=self.config.max_pause_ms * 1_000_000,
            on_expired=self._on_pause_expired,
            on_retired=self._on_retired,
        )
        # RELIABLE: agents send replies in bursts faster than real time; best effort would drop them.
        self.create_subscription(AudioChunk, "response_voice", self._on_voice, RELIABLE)
        self.create_subscription(Interruption, "interruption_signal", self._on_interruption, RELIABLE)
        # Periodic status only while there is something to report: an idle timer costs ~1 % of a
        # core in rclpy's executor. A new chunk restarts it.
        self._status_timer = self.create_timer(1.0 / self.config.status_rate_hz, self._on_status_timer)
        self._publish_state()
        self.loop.start()
        self.get_logger().info(
            f"player ready: sink={self.config.sink} rate={self.config.sample_rate} "
            f"block_ms={self.config.block_ms}"
            + (f" wav_path={self.config.wav_path}" if self.config.wav_path else "")
        )

    # -- callbacks: each one contained, so a surprise cannot stop the node ------------------

    def _on_voice(self, msg: AudioChunk) -> None:
        try:
            chunk = VoiceChunk(
                msg.stream_id,
                pcm_of(msg),
                int(msg.sample_rate),
                int(msg.channels),
                _stamp_ns(msg.header.stamp),
                bool(msg.end_of_stream),
            )
            self.engine.enqueue(chunk, self.loop.clock_ns())
        except ChunkRejected as error:
            stats = self.engine.stats
            self.get_logger().error(
                f"response_voice chunk of stream {msg.stream_id[:64]!r} rejected: {error} "
                f"(rejected so far: {stats.rejected})",
                throttle_duration_sec=LOG_EVERY_S,
            )
            return
        except Exception as error:
            self._callback_failed("response_voice", error)
            return
        self.loop.wake()
        if self._status_timer.is_canceled():
            self._status_timer.reset()

    def _on_interruption(self, msg: Interruption) -> None:
        try:
            if len(msg.stream_id) > MAX_STREAM_ID_CHARS:
                self._reject_interruption(f"stream_id of {len(msg.stream_id)} chars")
                return
            if msg.action in (Interruption.PAUSE, Interruption.RESUME):
                self._pause_or_resume(msg)
                return
            if msg.action != Interruption.CUT:
                self._reject_interruption(f"unknown action {msg.action}")
                return
            cut = Cut(msg.stream_id, _stamp_ns(msg.header.stamp), msg.reason[:64])
            outcome = self.loop.interrupt(cut)
            cut_ids = [state.stream_id for state in outcome.cut]
            if cut_ids:
                self.get_logger().info(f"interrupted ({cut.reason or 'no reason'}): cut {cut_ids}")
            else:  # common (a barge-in after the reply ended) and cheap to send: keep the log small
                self.get_logger().info(
                    f"interruption ({cut.reason or 'no reason'}) cut nothing",
                    throttle_duration_sec=LOG_EVERY_S,
                )
            self._publish_cut(outcome)
            self._publish_state()
        except Exception as error:
            self._callback_failed("interruption_signal", error)

    def _reject_interruption(self, why: str) -> None:
        self.interruptions_rejected += 1
        self.get_logger().error(
            f"interruption rejected: {why} ({self.interruptions_rejected} so far)",
            throttle_duration_sec=LOG_EVERY_S,
        )

    def _pause_or_resume(self, msg: Interruption) -> None:
        pause = msg.action == Interruption.PAUSE
        if not msg.stream_id:  # a blanket pause could hold replies nobody will resume
            self._reject_interruption(f"{'pause' if pause else 'resume'} without a stream_id")
            return
        state = self.loop.pause(msg.stream_id) if pause else self.loop.resume(msg.stream_id)
        verb = "paused" if pause else "resumed"
        if state is None:
            self.get_logger().info(
                f"{verb[:-1]} ({msg.reason[:64] or 'no reason'}) of {msg.stream_id[:64]!r}: not playing here",
                throttle_duration_sec=LOG_EVERY_S,
            )
            return
        self.get_logger().info(f"{verb} {state.stream_id!r} at {state.played_ms} ms ({msg.reason[:64]})")
        self._publish_state()

    def _on_pause_expired(self, outcome: CutOutcome) -> None:
        """On the player thread: nobody resumed or cut these paused replies in time."""
        self.get_logger().warning(
            f"paused longer than {self.config.max_pause_ms} ms, cut: {[s.stream_id for s in outcome.cut]}"
        )
        self._publish_cut(outcome)
        self._publish_state()

    def _on_retired(self, states: tuple[PlaybackState, ...]) -> None:
        """On the player thread: replies that ended while the next one already played (their
        `finished` would otherwise never be reported: the status follows the reply playing)."""
        with self._state_lock:
            for state in states:
                self._publish(self.status_pub, self._status_msg(state))

    def _on_played(self, block: PlayBlock, start_ns: int) -> None:
        """On the player thread: the AEC reference."""
        msg = make_audio_chunk(block.pcm, self.config.sample_rate, 1, _to_time(start_ns), block.stream_id)
        self._publish(self.played_pub, msg)

    def _on_status_timer(self) -> None:
        try:
            state = self.engine.status(self.loop.clock_ns())
            if state.speaking or state.paused or self._last_status != state:
                self._publish_state()
            elif state.queued_ms == 0:
                self._status_timer.cancel()  # idle: nothing changes until the next chunk
        except Exception as error:
            self._callback_failed("status timer", error)

    def _on_loop_error(self, error: BaseException) -> None:
        self.get_logger().error(
            f"player loop failed ({self.loop.errors} so far), going on: {type(error).__name__}: {error}",
            throttle_duration_sec=LOG_EVERY_S,
        )

    def _callback_failed(self, where: str, error: Exception) -> None:
        self.callback_errors += 1
        self.get_logger().error(
            f"{where} callback failed ({self.callback_errors} so far): {type(error).__name__}: {error}",
            throttle_duration_sec=LOG_EVERY_S,
        )

    # -- publishing (from callbacks and the player thread) ----------------------------------

    def _publish(self, publisher: Publisher, msg: Any) -> bool:
        """Publish; a failure (shutdown, overload) is logged and counted, not raised."""
        try:
            publisher.publish(msg)
        except Exception as error:
            self.publish_errors += 1
            self.get_logger().error(
                f"publish on {publisher.topic_name} failed ({self.publish_errors} so far): {error}",
                throttle_duration_sec=LOG_EVERY_S,
            )
            return False
        return True

    def _publish_state(self) -> None:
        """assistant_speaking (on change) and playback_status, now."""
        with self._state_lock:
            state = self.engine.status(self.loop.clock_ns())
            if state.speaking != self._speaking_sent and self._publish(
                self.speaking_pub, Bool(data=state.speaking)
            ):
                self._speaking_sent = state.speaking
            self._last_status = state
            self._publish(self.status_pub, self._status_msg(state))

    def _publish_cut(self, outcome: CutOutcome) -> None:
        """One status per cut reply that is not the one the regular status reports on."""
        current = self.engine.status(self.loop.clock_ns()).stream_id
        with self._state_lock:
            for state in outcome.cut:
                if state.stream_id != current:
                    self._publish(self.status_pub, self._status_msg(state))

    def _status_msg(self, state: PlaybackState) -> PlaybackStatus:
        msg = PlaybackStatus(
            stream_id=state.stream_id,
            played_ms=state.played_ms,
            queued_ms=state.queued_ms,
            speaking=state.speaking,
            finished=state.finished,
            interrupted=state.interrupted,
            paused=state.paused,
            starved=state.starved,
        )
        msg.header.stamp = self.get_clock().now().to_msg()
        return msg

    # -- stopping ---------------------------------------------------------------------------

    def before_shutdown(self) -> None:
        """Called by run_node on SIGINT/SIGTERM while the context is alive: stop playing, and
        leave assistant_speaking False (latched) and a final playback_status behind."""
        if self._shut_down:
            return
        self._shut_down = True
        try:
            outcome = self.loop.stop()
        except Exception as error:  # a sink that fails to close must not keep the state True
            self.get_logger().error(f"stopping the player failed: {type(error).__name__}: {error}")
            outcome = CutOutcome((), False)
        self._publish_cut(outcome)
        self._publish_state()

    def destroy_node(self) -> None:
        self.before_shutdown()  # not run yet when the node is destroyed without a signal
        stats = self.engine.stats
        self.get_logger().info(
            f"player stopped: chunks={stats.chunks} blocks={stats.blocks_played} "
            f"interruptions={stats.interruptions} streams_cut={stats.streams_cut} "
            f"pauses={stats.pauses} resumes={stats.resumes} pauses_expired={stats.pauses_expired} "
            f"dropped_late={stats.chunks_dropped_interrupted} dropped_closed={stats.chunks_dropped_closed} "
            f"superseded={stats.streams_superseded} "
            f"dropped_overflow_samples={stats.samples_dropped_overflow} "
            f"rejected={stats.rejected} loop_errors={self.loop.errors} blocks_failed={stats.blocks_failed} "
            f"callback_errors={self.callback_errors} publish_errors={self.publish_errors}"
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
