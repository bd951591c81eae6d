"""file_audio_publisher: WAV files -> `audio` (AudioChunk, 16 kHz mono), real time or faster.

Waits for `min_subscribers` subscribers on `audio`, plays the files in order (optionally looping),
then publishes True on the latched `file_audio_done` topic so tests and scripts can wait for the end.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk
from rclpy.node import Node
from std_msgs.msg import Bool

from by_your_command.audio.file_source import ChunkSchedule, Clip, FileSourceConfig, ScheduledChunk, load_clip
from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import LATCHED, STREAM

NS_PER_S = 1_000_000_000
WAIT_LOG_PERIOD_S = 5.0
START_CHECK_PERIOD_S = 0.05  # how often the subscribers playing waits for are checked


class FileAudioPublisher(Node):
    def __init__(self) -> None:
        super().__init__("file_audio_publisher")
        self.config = declare_config(self, FileSourceConfig)
        clips = [Clip(Path(f).stem, load_clip(f, self.config.sample_rate)) for f in self.config.files]
        if self.config.lead_silence_ms:
            silence = np.zeros(self.config.lead_silence_ms * self.config.sample_rate // 1000, dtype=np.int16)
            clips.insert(0, Clip("lead_silence", silence))
        self.schedule = ChunkSchedule(clips, self.config)
        self.audio_pub = self.create_publisher(AudioChunk, "audio", STREAM)
        self.done_pub = self.create_publisher(Bool, "file_audio_done", LATCHED)
        self.done_pub.publish(Bool(data=False))
        self.publish_failures = 0
        self._start_ns = 0
        self._waiting_since = time.monotonic()
        self._stop = threading.Event()
        # Chunks are paced by a thread of their own, as audio_capture's come from the device: an
        # executor wake-up per chunk (a timer) costs ~0.5 ms of rclpy time each.
        self._pacer = threading.Thread(target=self._play, name="file-pacer", daemon=True)
        self.waiting_timer = self.create_timer(START_CHECK_PERIOD_S, self._check_start)
        seconds = sum(len(c.samples) for c in clips) / self.config.sample_rate
        self.get_logger().info(
            f"{len(self.config.files)} file(s), {seconds:.2f} s of audio at {self.config.rate_factor}x; "
            f"waiting for {self.config.min_subscribers} subscriber(s) on 'audio'"
        )

    def _waiting_for(self) -> str:
        """The topic still missing subscribers before playing starts, or ''."""
        if self.audio_pub.get_subscription_count() < self.config.min_subscribers:
            return "'audio'"
        wait_topic = self.config.wait_for_topic
        if wait_topic and self.count_subscribers(wait_topic) < 1:
            return repr(wait_topic)
        return ""

    def _check_start(self) -> None:
        waiting_for = self._waiting_for()
        if waiting_for:
            now = time.monotonic()
            if now - self._waiting_since > WAIT_LOG_PERIOD_S:
                self._waiting_since = now
                self.get_logger().info(f"still waiting for subscribers on {waiting_for}")
            return
        self.waiting_timer.cancel()
        self._start_ns = int(self.get_clock().now().nanoseconds)
        self.get_logger().info("subscriber found: playing")
        self._pacer.start()

    def _play(self) -> None:
        started = time.monotonic()
        try:
            while not self._stop.is_set() and not self.schedule.finished:
                wait_s = self.schedule.next_due_s() - (time.monotonic() - started)
                if wait_s > 0 and self._stop.wait(wait_s):
                    return
                for chunk in self.schedule.due(time.monotonic() - started):
                    self._publish(chunk)
            if self.schedule.finished:
                self.done_pub.publish(Bool(data=True))
                self.get_logger().info(
                    f"done: {self.schedule.samples_sent / self.config.sample_rate:.2f} s published, "
                    f"{self.publish_failures} publish failures"
                )
        except Exception as error:  # shutting down (the context is gone), or a bug: never unseen
            if not self._stop.is_set():
                self.get_logger().error(f"file playback stopped: {error!r}")

    def _publish(self, chunk: ScheduledChunk) -> None:
        # Stamps follow the audio's own timeline (as if captured live), also when played faster:
        # consumers check that blocks are contiguous and would take compressed stamps for gaps.
        stamp_ns = self._start_ns + int(chunk.offset_s * NS_PER_S)
        msg = make_audio_chunk(
            chunk.samples,
            self.config.sample_rate,
            1,
            Time(sec=stamp_ns // NS_PER_S, nanosec=stamp_ns % NS_PER_S),
            chunk.stream_id,
        )
        try:
            self.audio_pub.publish(msg)
        except Exception as error:  # rclpy raises RCLError under overload: count, never crash
            self.publish_failures += 1
            self.get_logger().error(f"publish failed ({self.publish_failures} so far): {error}")

    def destroy_node(self) -> None:
        self._stop.set()
        if self._pacer.is_alive():
            self._pacer.join(timeout=2)
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    from by_your_command.nodes._runtime import run_node

    run_node(FileAudioPublisher, args if args is not None else sys.argv)


if __name__ == "__main__":
    main()
