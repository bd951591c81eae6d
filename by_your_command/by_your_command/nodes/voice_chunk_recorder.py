"""voice_chunk_recorder: prompt_voice -> one WAV per utterance, or response_voice -> one WAV per stream.

input_mode `utterance` subscribes `prompt_voice` (AudioDataUtterance); `stream` subscribes
`response_voice` (AudioChunk). Remap either topic to record something else. Files are written at the
rate each message carries. Logic lives in audio/recording.py.
"""

from __future__ import annotations

import sys
import time
from datetime import datetime
from pathlib import Path

import numpy as np
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance
from rclpy.node import Node

from by_your_command.audio.recording import RecorderConfig, StreamRecorder, UtteranceRecorder
from by_your_command.nodes._audio_msgs import pcm_of
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import RELIABLE, STREAM

POLL_PERIOD_S = 0.1


class VoiceChunkRecorder(Node):
    def __init__(self) -> None:
        super().__init__("voice_chunk_recorder")
        self.config = declare_config(self, RecorderConfig)
        directory = self.config.directory()
        self.recorder: UtteranceRecorder | StreamRecorder
        if self.config.input_mode == "utterance":
            self.recorder = UtteranceRecorder(directory, self.config.close_timeout_sec, _now)
            self.create_subscription(AudioDataUtterance, "prompt_voice", self._on_utterance, RELIABLE)
        else:
            self.recorder = StreamRecorder(directory, self.config.close_timeout_sec, _now)
            self.create_subscription(AudioChunk, "response_voice", self._on_stream, STREAM)
        self.rejected = 0
        self.create_timer(POLL_PERIOD_S, self._poll)
        self.get_logger().info(f"recording {self.config.input_mode} audio into {directory}")

    def _on_utterance(self, msg: AudioDataUtterance) -> None:
        if not isinstance(self.recorder, UtteranceRecorder):
            return
        samples = np.frombuffer(msg.int16_data, dtype=np.int16)
        try:
            closed = self.recorder.add(
                msg.utterance_id, samples, int(msg.sample_rate), msg.is_utterance_end, time.monotonic()
            )
        except (ValueError, OSError) as error:
            self._reject(error)
            return
        self._log_closed(closed)

    def _on_stream(self, msg: AudioChunk) -> None:
        if not isinstance(self.recorder, StreamRecorder):
            return
        try:
            closed = self.recorder.add(
                msg.stream_id, pcm_of(msg), int(msg.sample_rate), int(msg.channels), time.monotonic()
            )
        except (ValueError, OSError) as error:
            self._reject(error)
            return
        self._log_closed(closed)

    def _reject(self, error: Exception) -> None:
        self.rejected += 1
        self.get_logger().error(f"audio not recorded ({self.rejected} chunks so far): {error}")

    def _poll(self) -> None:
        self._log_closed(self.recorder.poll(time.monotonic()))

    def _log_closed(self, paths: list[Path]) -> None:
        for path in paths:
            self.get_logger().info(f"wrote {path}")

    def destroy_node(self) -> None:
        self.recorder.close()
        super().destroy_node()


def _now() -> datetime:
    return datetime.now()


def main(args: list[str] | None = None) -> None:
    from by_your_command.nodes._runtime import run_node

    run_node(VoiceChunkRecorder, args if args is not None else sys.argv)


if __name__ == "__main__":
    main()
