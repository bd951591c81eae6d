"""Response playback without ROS: per-response queues, small blocks, instant interruption.

`PlaybackEngine` is the bookkeeping (what is queued, what has been played, speaking or not) and is
driven by explicit timestamps so it can be tested without a clock. `PlayerLoop` is the thread that
feeds an `AudioSink` block by block; an interruption flushes every queue and cancels the block
waiting for the sink, so at most the block already playing is heard afterwards.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from by_your_command.audio.pcm import Int16Array, StreamResampler, to_mono
from by_your_command.audio.sinks import AudioSink

_LOG = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
MAX_BLOCK_MS = 40
REMEMBERED_INTERRUPTIONS = 64


@dataclass(frozen=True)
class PlayerConfig:
    sink: str = field(default="device", metadata={"help": "device (PortAudio) or wav (file, no sound card)"})
    device: str = field(default="", metadata={"help": "output device index or name substring; '' = default"})
    sample_rate: int = field(default=24000, metadata={"help": "rate sent to the sink; input is resampled"})
    block_ms: int = field(default=20, metadata={"help": "playback block; interruption latency <= 1 block"})
    wav_path: str = field(default="", metadata={"help": "sink=wav: file to write (required)"})
    realtime: bool = field(default=True, metadata={"help": "sink=wav: pace like a device (False: drain now)"})
    status_rate_hz: float = field(default=10.0, metadata={"help": "playback_status rate while active"})
    max_queue_ms: int = field(default=300_000, metadata={"help": "queued audio beyond this is dropped"})

    def __post_init__(self) -> None:
        if self.sink not in ("device", "wav"):
            raise ValueError(f"sink must be 'device' or 'wav', got {self.sink!r}")
        if self.sink == "wav" and not self.wav_path:
            raise ValueError("sink 'wav' needs wav_path (the file to write)")
        if self.sample_rate <= 0:
            raise ValueError(f"sample_rate must be positive, got {self.sample_rate}")
        if not 1 <= self.block_ms <= MAX_BLOCK_MS:
            raise ValueError(f"block_ms must be within 1..{MAX_BLOCK_MS}, got {self.block_ms}")
        if self.status_rate_hz <= 0:
            raise ValueError(f"status_rate_hz must be positive, got {self.status_rate_hz}")
        if self.max_queue_ms <= 0:
            raise ValueError(f"max_queue_ms must be positive, got {self.max_queue_ms}")

    @property
    def block_samples(self) -> int:
        return max(1, self.sample_rate * self.block_ms // 1000)


@dataclass(frozen=True)
class PlayBlock:
    stream_id: str
    pcm: Int16Array


@dataclass(frozen=True)
class PlaybackState:
    stream_id: str
    played_ms: int
    queued_ms: int
    speaking: bool
    finished: bool
    interrupted: bool


@dataclass
class PlayerStats:
    chunks: int = 0
    samples_dropped_overflow: int = 0
    chunks_dropped_interrupted: int = 0  # late chunks of a response that was already interrupted
    chunks_rejected: int = 0  # malformed input
    interruptions: int = 0
    blocks_played: int = 0


class _Stream:
    def __init__(self, stream_id: str, resampler: StreamResampler) -> None:
        self.stream_id = stream_id
        self.resampler = resampler
        self.source_rate = 0
        self.queue: deque[Int16Array] = deque()
        self.queued = 0
        self.committed = 0  # samples handed to the sink (some may still be playing)

    def take(self, count: int) -> Int16Array:
        parts: list[Int16Array] = []
        need = count
        while need and self.queue:
            head = self.queue[0]
            if len(head) <= need:
                parts.append(self.queue.popleft())
                need -= len(head)
            else:
                parts.append(head[:need])
                self.queue[0] = head[need:]
                need = 0
        taken = np.concatenate(parts) if parts else np.zeros(0, dtype=np.int16)
        self.queued -= len(taken)
        return taken


class PlaybackEngine:
    """Queues per response (stream_id), hands out blocks, tracks what was played. Thread-safe."""

    def __init__(self, sample_rate: int, block_samples: int, max_queue_samples: int) -> None:
        self.sample_rate = sample_rate
        self.block_samples = block_samples
        self.max_queue_samples = max_queue_samples
        self.stats = PlayerStats()
        self.cancel = threading.Event()  # set by interrupt(): the block waiting for the sink is void
        self._lock = threading.Lock()
        self._streams: deque[_Stream] = deque()
        self._last: _Stream | None = None  # the most recent stream that played (for status)
        self._last_interrupted = False
        self._play_end_ns = 0  # when the audio handed to the sink so far ends
        self._interrupted_ids: deque[str] = deque(maxlen=REMEMBERED_INTERRUPTIONS)

    def _ms(self, samples: int) -> int:
        return samples * 1000 // self.sample_rate

    def enqueue(self, stream_id: str, pcm: Int16Array, sample_rate: int, channels: int) -> None:
        """Queue one chunk of a response; raises ValueError on malformed audio (nothing queued)."""
        if sample_rate <= 0:
            self.stats.chunks_rejected += 1
            raise ValueError(f"chunk of stream {stream_id!r} has sample_rate {sample_rate}")
        try:
            mono = to_mono(pcm, channels)
        except ValueError:
            self.stats.chunks_rejected += 1
            raise
        with self._lock:
            self.stats.chunks += 1
            if stream_id and stream_id in self._interrupted_ids:
                self.stats.chunks_dropped_interrupted += 1
                return
            stream = self._stream_for(stream_id, sample_rate)
            samples = stream.resampler.push(mono)
            room = self.max_queue_samples - sum(s.queued for s in self._streams)
            if len(samples) > room:
                self.stats.samples_dropped_overflow += len(samples) - max(room, 0)
                samples = samples[: max(room, 0)]
            if len(samples):
                stream.queue.append(samples)
                stream.queued += len(samples)

    def _stream_for(self, stream_id: str, sample_rate: int) -> _Stream:
        resampler = StreamResampler(sample_rate, self.sample_rate)
        if self._streams and self._streams[-1].stream_id == stream_id:
            stream = self._streams[-1]
            if stream.source_rate != sample_rate:  # the rate changed mid-stream: new resampler
                self._flush_resampler(stream)
                stream.resampler, stream.source_rate = resampler, sample_rate
            return stream
        stream = _Stream(stream_id, resampler)
        stream.source_rate = sample_rate
        self._streams.append(stream)
        return stream

    @staticmethod
    def _flush_resampler(stream: _Stream) -> None:
        tail = stream.resampler.flush()
        if len(tail):
            stream.queue.append(tail)
            stream.queued += len(tail)

    def next_block(self) -> PlayBlock | None:
        """The next block to play (≤ block_samples of one response), or None when nothing is queued."""
        with self._lock:
            self.cancel.clear()
            while self._streams:
                head = self._streams[0]
                if head.queued == 0:
                    self._flush_resampler(head)  # ran dry: release the held-back margin
                if head.queued:
                    if self._last is not head:
                        self._last, self._last_interrupted = head, False
                    return PlayBlock(head.stream_id, head.take(self.block_samples))
                if len(self._streams) == 1:
                    return None  # keep the (dry) head: more chunks of it may come
                self._streams.popleft()
            return None

    def commit(self, block: PlayBlock, start_ns: int) -> None:
        """The sink started playing `block` at `start_ns`."""
        with self._lock:
            if self._last is not None and self._last.stream_id == block.stream_id:
                self._last.committed += len(block.pcm)
            self._play_end_ns = start_ns + len(block.pcm) * NS_PER_S // self.sample_rate
            self.stats.blocks_played += 1

    def interrupt(self, now_ns: int) -> bool:
        """Flush everything queued; True if something was playing or queued."""
        with self._lock:
            busy = bool(sum(s.queued for s in self._streams)) or now_ns < self._play_end_ns
            for stream in self._streams:
                if stream.stream_id:
                    self._interrupted_ids.append(stream.stream_id)
            self._streams.clear()
            self.cancel.set()
            if busy:
                self.stats.interruptions += 1
                self._last_interrupted = True
            return busy

    def playing_until_ns(self) -> int:
        with self._lock:
            return self._play_end_ns

    def speaking(self, now_ns: int) -> bool:
        with self._lock:
            return self._speaking(now_ns)

    def _speaking(self, now_ns: int) -> bool:
        return now_ns < self._play_end_ns or any(s.queued for s in self._streams)

    def status(self, now_ns: int) -> PlaybackState:
        with self._lock:
            speaking = self._speaking(now_ns)
            last = self._last
            if last is None:
                return PlaybackState("", 0, 0, speaking, False, False)
            unplayed = max(0, self._play_end_ns - now_ns) * self.sample_rate // NS_PER_S
            played = max(0, last.committed - unplayed) if now_ns < self._play_end_ns else last.committed
            queued = last.queued if last in self._streams else 0
            interrupted = self._last_interrupted
            finished = not interrupted and queued == 0 and now_ns >= self._play_end_ns
            return PlaybackState(
                last.stream_id, self._ms(played), self._ms(queued), speaking, finished, interrupted
            )


class PlayerLoop:
    """Feeds the sink from the engine on its own thread and reports what happened.

    `on_played(block, start_ns)` gets every block the sink accepted (the AEC reference);
    `on_change()` is called when speaking flips, a response starts or one ends.
    """

    def __init__(
        self,
        engine: PlaybackEngine,
        sink: AudioSink,
        on_played: Callable[[PlayBlock, int], None],
        on_change: Callable[[], None],
        clock_ns: Callable[[], int] = time.time_ns,
        idle_poll_s: float = 0.005,
    ) -> None:
        self.engine = engine
        self.sink = sink
        self._on_played = on_played
        self._on_change = on_change
        self._clock_ns = clock_ns
        self._idle_poll_s = idle_poll_s
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="player", daemon=True)
        self._was_speaking = False
        self._current_stream: str | None = None

    def start(self) -> None:
        self._thread.start()

    def wake(self) -> None:
        """New audio queued: don't wait for the idle poll."""
        self._wake.set()

    def interrupt(self) -> bool:
        busy = self.engine.interrupt(self._clock_ns())
        self.sink.flush()
        self._wake.set()
        return busy

    def stop(self) -> None:
        self._stop.set()
        self.engine.cancel.set()
        self._wake.set()
        self._thread.join(timeout=5)
        self.sink.close()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                block = self.engine.next_block()
                if block is None:
                    self._check_speaking()
                    self._wait_idle()
                    continue
                start_ns = self.sink.play(block.pcm, self.engine.cancel)
                if start_ns is None:
                    continue  # interrupted while waiting for the sink: the block is void
                self.engine.commit(block, start_ns)
                self._on_played(block, start_ns)
                if block.stream_id != self._current_stream or not self._was_speaking:
                    self._current_stream = block.stream_id
                    self._was_speaking = True
                    self._on_change()
        except Exception:  # the thread must not die silently
            _LOG.exception("player thread failed")
            raise

    def _check_speaking(self) -> None:
        speaking = self.engine.speaking(self._clock_ns())
        if speaking != self._was_speaking:
            self._was_speaking = speaking
            self._on_change()

    def _wait_idle(self) -> None:
        # While the last block plays out, wake at its end so speaking goes False on time.
        remaining_s = (self.engine.playing_until_ns() - self._clock_ns()) / NS_PER_S
        timeout = min(self._idle_poll_s * 4, remaining_s) if remaining_s > 0 else self._idle_poll_s * 4
        self._wake.wait(max(timeout, 0.001))
        self._wake.clear()
