"""Response playback without ROS: per-response queues, small blocks, precise interruption.

`PlaybackEngine` is the bookkeeping (what is queued, what has been played, speaking or not) and is
driven by explicit timestamps so it can be tested without a clock. `PlayerLoop` is the supervised
thread that feeds an `AudioSink` block by block. An interruption names what it cuts (a stream_id,
or every reply that started up to a time); the cut replies' queues are flushed and, if one of them
is in the sink, the sink drops its rest, so at most the block playing is heard, up to the cut.

A reply can also be paused (an agent heard speech over it and is finding out whether it is a real
interruption) and resumed: the sink drops what it holds of it, the unplayed rest goes back to the
front of its queue, and played_ms goes on from where it stopped, so a later cut reports what the
listener heard of the whole reply. Replies behind a paused one wait; a pause nobody resolves within
`max_pause_ms` becomes a cut (the agent that paused it may be gone).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from by_your_command.audio.pcm import Int16Array, StreamResampler, to_mono
from by_your_command.audio.sinks import AudioSink, samples_played_by

_LOG = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
MAX_BLOCK_MS = 40
# What an inbound chunk may claim; anything else is rejected before any work is done on it.
MIN_CHUNK_RATE = 8_000
MAX_CHUNK_RATE = 192_000
MAX_CHUNK_CHANNELS = 8
MAX_RATIO_TERM = 1000  # resampling filters grow with max(up, down) of the reduced rate ratio
MAX_STREAM_ID_CHARS = 256
REMEMBERED_STREAMS = 256  # cut / closed stream ids remembered to drop their late chunks
IN_FLIGHT_HORIZON_NS = NS_PER_S  # played blocks are remembered this long (beyond any sink latency)
ERROR_BACKOFF_S = (0.01, 1.0)  # the loop's pause after an error: first, and at most
IDLE_WAIT_S = 1.0  # the loop's longest sleep with nothing to play (new audio and cuts wake it)


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
    max_chunk_ms: int = field(default=10_000, metadata={"help": "longer response_voice chunks are rejected"})
    max_pause_ms: int = field(
        default=5000,
        metadata={
            "help": "a reply paused (barge-in being judged) longer than this is cut: its agent is gone"
        },
    )

    def __post_init__(self) -> None:
        if self.sink not in ("device", "wav"):
            raise ValueError(f"sink must be 'device' or 'wav', got {self.sink!r}")
        if self.sink == "wav" and not self.wav_path:
            raise ValueError("sink 'wav' needs wav_path (the file to write)")
        if not MIN_CHUNK_RATE <= self.sample_rate <= MAX_CHUNK_RATE:
            raise ValueError(
                f"sample_rate must be within {MIN_CHUNK_RATE}..{MAX_CHUNK_RATE}, got {self.sample_rate}"
            )
        if not 1 <= self.block_ms <= MAX_BLOCK_MS:
            raise ValueError(f"block_ms must be within 1..{MAX_BLOCK_MS}, got {self.block_ms}")
        if self.status_rate_hz <= 0:
            raise ValueError(f"status_rate_hz must be positive, got {self.status_rate_hz}")
        if self.max_queue_ms <= 0:
            raise ValueError(f"max_queue_ms must be positive, got {self.max_queue_ms}")
        if self.max_chunk_ms <= 0:
            raise ValueError(f"max_chunk_ms must be positive, got {self.max_chunk_ms}")
        if not 0 < self.max_pause_ms <= 60_000:
            raise ValueError(f"max_pause_ms must be within 1..60000, got {self.max_pause_ms}")

    @property
    def block_samples(self) -> int:
        return max(1, self.sample_rate * self.block_ms // 1000)


@dataclass(frozen=True)
class VoiceChunk:
    """One inbound piece of a reply, as the message carried it (nothing about it is trusted)."""

    stream_id: str
    pcm: Int16Array  # interleaved
    sample_rate: int
    channels: int = 1
    stamp_ns: int = 0  # sender's time of the first sample; 0 = unstamped (arrival time is used)
    end_of_stream: bool = False


@dataclass(frozen=True)
class Cut:
    """What an interruption cuts: the reply `stream_id`, or (empty id) every reply whose first
    chunk is stamped at or before `up_to_ns`; `up_to_ns` 0 = everything the player holds now."""

    stream_id: str = ""
    up_to_ns: int = 0
    reason: str = ""


class ChunkRejected(ValueError):
    """An inbound chunk was refused; `reason` is the counter it was counted under."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


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
    finished: bool  # played to its end_of_stream
    interrupted: bool
    starved: bool = False  # ran dry before its end_of_stream: the next chunk is late
    paused: bool = False  # held by a pause: its rest is kept until it is resumed or cut


@dataclass(frozen=True)
class CutOutcome:
    cut: tuple[PlaybackState, ...]  # the state of every reply the interruption cut
    flush_sink: bool  # a cut reply was in the sink: its rest must be dropped there


@dataclass
class PlayerStats:
    chunks: int = 0  # accepted
    rejected: dict[str, int] = field(default_factory=dict)  # malformed input, by reason
    chunks_dropped_interrupted: int = 0  # late chunks of a reply that was already cut
    chunks_dropped_closed: int = 0  # chunks of a reply that had ended or been left behind
    samples_dropped_overflow: int = 0
    interruptions: int = 0  # interruptions that cut something
    pauses: int = 0  # pauses that held a reply
    resumes: int = 0
    pauses_expired: int = 0  # paused longer than max_pause_ms: cut
    streams_cut: int = 0
    streams_superseded: int = 0  # ran dry without end_of_stream while the next reply waited
    blocks_played: int = 0
    blocks_failed: int = 0  # lost to an error in the player loop

    @property
    def chunks_rejected(self) -> int:
        return sum(self.rejected.values())


def chunk_problem(chunk: VoiceChunk, sink_rate: int, max_chunk_ms: int) -> ChunkRejected | None:
    """Why `chunk` cannot be played, or None. Cheap: it runs before any work on the samples."""
    rate, channels, count = chunk.sample_rate, chunk.channels, len(chunk.pcm)
    if not MIN_CHUNK_RATE <= rate <= MAX_CHUNK_RATE:
        return ChunkRejected("sample_rate", f"{rate} Hz is outside {MIN_CHUNK_RATE}..{MAX_CHUNK_RATE}")
    ratio = Fraction(sink_rate, rate)
    if max(ratio.numerator, ratio.denominator) > MAX_RATIO_TERM:
        return ChunkRejected("resample_ratio", f"{rate} -> {sink_rate} Hz needs ratio {ratio}")
    if not 1 <= channels <= MAX_CHUNK_CHANNELS:
        return ChunkRejected("channels", f"{channels} channels is outside 1..{MAX_CHUNK_CHANNELS}")
    if count % channels:
        return ChunkRejected(
            "partial_frame", f"{count} samples is not a whole number of {channels}-channel frames"
        )
    if count // channels * 1000 > max_chunk_ms * rate:
        return ChunkRejected("too_long", f"{count // channels} frames at {rate} Hz exceed {max_chunk_ms} ms")
    if len(chunk.stream_id) > MAX_STREAM_ID_CHARS:
        return ChunkRejected(
            "stream_id", f"stream_id of {len(chunk.stream_id)} chars exceeds {MAX_STREAM_ID_CHARS}"
        )
    return None


class _RecentIds:
    """The last `size` ids added, for membership tests (bounded: ids come from the network)."""

    def __init__(self, size: int) -> None:
        self._order: deque[str] = deque()
        self._ids: set[str] = set()
        self._size = size

    def add(self, stream_id: str) -> None:
        if not stream_id or stream_id in self._ids:
            return
        self._order.append(stream_id)
        self._ids.add(stream_id)
        if len(self._order) > self._size:
            self._ids.discard(self._order.popleft())

    def __contains__(self, stream_id: str) -> bool:
        return stream_id in self._ids


class _Stream:
    """One reply: its queue at the sink rate and what of it was handed to the sink."""

    def __init__(self, stream_id: str, start_ns: int, resampler: StreamResampler) -> None:
        self.stream_id = stream_id
        self.start_ns = start_ns  # first chunk's stamp (or arrival time): what a blanket cut compares
        self.resampler = resampler
        self.queue: deque[Int16Array] = deque()
        self.queued = 0
        self.committed = 0  # samples handed to the sink (the last ones may still be playing)
        self.play_end_ns = 0  # when its last committed block ends
        self.started = False
        self.ended = False  # end_of_stream received
        self.cut_at_ns: int | None = None
        self.frozen_played = 0  # samples heard before the cut
        self.paused_at_ns: int | None = None
        # Pieces put back at the front of the queue while one of its blocks was handed out and not
        # yet in the sink: that block, if given back, goes after them (it comes later in the reply).
        self.requeued_ahead = 0
        self.end_reported = False  # a status saying it finished was handed out

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
        taken = np.concatenate(parts) if len(parts) != 1 else parts[0]
        self.queued -= len(taken)
        return taken


@dataclass
class _InFlight:
    """A block the sink accepted and may still be playing."""

    stream: _Stream
    pcm: Int16Array
    start_ns: int
    end_ns: int


class PlaybackEngine:
    """Queues per response (stream_id), hands out blocks, tracks what was played. Thread-safe."""

    def __init__(
        self, sample_rate: int, block_samples: int, max_queue_samples: int, max_chunk_ms: int = 10_000
    ) -> None:
        self.sample_rate = sample_rate
        self.block_samples = block_samples
        self.max_queue_samples = max_queue_samples
        self.max_chunk_ms = max_chunk_ms
        self.stats = PlayerStats()
        self._lock = threading.Lock()
        self._streams: deque[_Stream] = deque()  # waiting or playing, in play order
        self._queued_total = 0
        self._current: _Stream | None = None  # the reply status reports on
        # Replies that were `_current` before the one now: their end is reported once it comes
        # (back to back, the next reply's status would otherwise hide that the first finished).
        self._retired: list[_Stream] = []
        self._pending: _Stream | None = None  # stream of the block handed out, not yet committed
        self._in_flight: deque[_InFlight] = deque()
        self._play_end_ns = 0  # when the audio handed to the sink so far ends
        self._cut_ids = _RecentIds(REMEMBERED_STREAMS)
        self._closed_ids = _RecentIds(REMEMBERED_STREAMS)
        self._cut_up_to_ns = 0  # replies starting at or before this were cut by a blanket cut

    def _ms(self, samples: int) -> int:
        return samples * 1000 // self.sample_rate

    # -- input ------------------------------------------------------------------------------

    def enqueue(self, chunk: VoiceChunk, now_ns: int) -> None:
        """Queue one chunk of a response; raises ChunkRejected (counted) on malformed input."""
        problem = chunk_problem(chunk, self.sample_rate, self.max_chunk_ms)
        if problem is None:
            try:
                self._enqueue(chunk, to_mono(chunk.pcm, chunk.channels), now_ns)
                return
            except ChunkRejected as error:
                problem = error
        with self._lock:
            self.stats.rejected[problem.reason] = self.stats.rejected.get(problem.reason, 0) + 1
        raise problem

    def _enqueue(self, chunk: VoiceChunk, mono: Int16Array, now_ns: int) -> None:
        stream_id = chunk.stream_id
        with self._lock:
            if stream_id in self._cut_ids:
                self.stats.chunks_dropped_interrupted += 1
                return
            stream = self._open_stream(stream_id)
            if stream is None:
                if stream_id in self._closed_ids:
                    self.stats.chunks_dropped_closed += 1
                    return
                start_ns = chunk.stamp_ns if chunk.stamp_ns > 0 else now_ns
                if 0 < start_ns <= self._cut_up_to_ns:  # stamped before a blanket cut: part of what it cut
                    self._cut_ids.add(stream_id)
                    self.stats.chunks_dropped_interrupted += 1
                    return
                stream = _Stream(stream_id, start_ns, self._resampler(chunk.sample_rate))
                self._streams.append(stream)
            elif stream.resampler.from_rate != chunk.sample_rate:  # the rate changed mid-stream
                resampler = self._resampler(chunk.sample_rate)
                self._queue(stream, stream.resampler.flush())
                stream.resampler = resampler
            self.stats.chunks += 1
            self._queue(stream, stream.resampler.push(mono))
            if chunk.end_of_stream:
                self._queue(stream, stream.resampler.flush())
                stream.ended = True
                self._closed_ids.add(stream_id)

    def _resampler(self, from_rate: int) -> StreamResampler:
        try:
            return StreamResampler(from_rate, self.sample_rate)
        except ValueError as error:  # chunk_problem let it through, but the resampler knows best
            raise ChunkRejected("resample_ratio", str(error)) from None

    def _open_stream(self, stream_id: str) -> _Stream | None:
        for stream in self._streams:
            if stream.stream_id == stream_id and not stream.ended:
                return stream
        return None

    def _queue(self, stream: _Stream, samples: Int16Array) -> None:
        room = max(self.max_queue_samples - self._queued_total, 0)
        if len(samples) > room:
            self.stats.samples_dropped_overflow += len(samples) - room
            samples = samples[:room]
        if len(samples):
            stream.queue.append(samples)
            stream.queued += len(samples)
            self._queued_total += len(samples)

    # -- the player loop's side -------------------------------------------------------------

    def next_block(self) -> PlayBlock | None:
        """The next block to play (≤ block_samples of one response), or None when nothing is queued
        (or the reply in front is paused)."""
        with self._lock:
            while self._streams:
                head = self._streams[0]
                if head.paused_at_ns is not None:
                    return None
                if head.queued == 0 and not head.ended:
                    self._queue(head, head.resampler.flush())  # ran dry: release the held-back tail
                if head.queued:
                    pcm = head.take(self.block_samples)
                    self._queued_total -= len(pcm)
                    head.started = True
                    head.requeued_ahead = 0
                    self._retire_current(head)
                    self._current = self._pending = head
                    return PlayBlock(head.stream_id, pcm)
                if not head.ended and len(self._streams) == 1:
                    return None  # keep the (dry) head: more chunks of it may come
                self._streams.popleft()
                if not head.ended:  # ran dry and the next reply waits: move on, count it
                    self._closed_ids.add(head.stream_id)
                    self.stats.streams_superseded += 1
                elif not head.started:
                    self._retire_current(head)
                    self._current = head  # a reply with no audio at all: report it finished
            return None

    def _retire_current(self, new: _Stream) -> None:
        old = self._current
        if old is not None and old is not new and old.cut_at_ns is None and old not in self._retired:
            self._retired.append(old)

    def take_retired(self, now_ns: int) -> tuple[PlaybackState, ...]:
        """The final state of each earlier reply that has stopped sounding since (once each)."""
        with self._lock:
            done = [s for s in self._retired if s.cut_at_ns is not None or now_ns >= s.play_end_ns]
            self._retired = [s for s in self._retired if s not in done]
            unreported = [s for s in done if s.cut_at_ns is None and not s.end_reported]
            for stream in unreported:
                stream.end_reported = True
            return tuple(self._state(s, now_ns) for s in unreported)

    def wants(self, block: PlayBlock) -> bool:
        """False if the handed-out block's reply was cut (then `give_back` drops it), paused, or
        had audio put back ahead of it since (then `give_back` requeues it in its place)."""
        with self._lock:
            pending = self._pending
            # Not if audio that comes before it in the reply was put back in its queue meanwhile
            # (a pause, or a flush for another reply's cut): it is given back to go after that.
            return (
                pending is not None
                and pending.cut_at_ns is None
                and pending.paused_at_ns is None
                and pending.requeued_ahead == 0
            )

    def give_back(self, block: PlayBlock) -> None:
        """The sink did not take `block`: requeue it at the front of its reply, unless that was cut."""
        with self._lock:
            stream, self._pending = self._pending, None
            if stream is None or stream.cut_at_ns is not None:
                return
            self._requeue(stream, block.pcm, after=stream.requeued_ahead)

    def _requeue(self, stream: _Stream, pcm: Int16Array, after: int = 0) -> None:
        """Put `pcm` back at the front of its reply's queue (behind the first `after` pieces)."""
        stream.queue.insert(min(after, len(stream.queue)), pcm)
        stream.queued += len(pcm)
        self._queued_total += len(pcm)
        if stream not in self._streams:
            self._streams.appendleft(stream)

    def drop_pending(self) -> None:
        """The loop failed with a block in hand: it is lost (counted), the rest stays consistent."""
        with self._lock:
            if self._pending is not None:
                self._pending = None
                self.stats.blocks_failed += 1

    def commit(self, block: PlayBlock, start_ns: int) -> None:
        """The sink started playing `block` at `start_ns`."""
        with self._lock:
            stream, self._pending = self._pending, None
            if stream is None or stream.cut_at_ns is not None:
                return  # the loop checks `wants` first: only a misuse gets here
            if stream.paused_at_ns is not None:  # paused between `wants` and the sink: play it later
                self._requeue(stream, block.pcm, after=stream.requeued_ahead)
                return
            end_ns = start_ns + len(block.pcm) * NS_PER_S // self.sample_rate
            # A device starts a block up to its latency after accepting it, so an entry may only be
            # forgotten once it ended well before the newest block starts.
            while self._in_flight and self._in_flight[0].end_ns <= start_ns - IN_FLIGHT_HORIZON_NS:
                self._in_flight.popleft()
            self._in_flight.append(_InFlight(stream, block.pcm, start_ns, end_ns))
            stream.committed += len(block.pcm)
            stream.play_end_ns = end_ns
            self._play_end_ns = max(self._play_end_ns, end_ns)
            self.stats.blocks_played += 1

    # -- interruption -----------------------------------------------------------------------

    def interrupt(self, cut: Cut, now_ns: int) -> CutOutcome:
        """Cut what `cut` names at `now_ns`: flush their queues, freeze their played_ms."""
        with self._lock:
            known = list(self._streams)
            for other in (self._current, self._pending, *(entry.stream for entry in self._in_flight)):
                if other is not None and other not in known:
                    known.append(other)
            if cut.stream_id:
                self._cut_ids.add(cut.stream_id)
                targets = [s for s in known if s.stream_id == cut.stream_id]
            elif cut.up_to_ns > 0:
                self._cut_up_to_ns = max(self._cut_up_to_ns, cut.up_to_ns)
                targets = [s for s in known if s.start_ns <= cut.up_to_ns]
            else:
                targets = known
            targets = [s for s in targets if s.cut_at_ns is None and not self._finished(s, now_ns)]
            for stream in targets:
                stream.frozen_played = self._played(stream, now_ns)
                stream.cut_at_ns = now_ns
                self._queued_total -= stream.queued
                stream.queue.clear()
                stream.queued = 0
                self._cut_ids.add(stream.stream_id)
            self._streams = deque(s for s in self._streams if s.cut_at_ns is None)
            flush = any(e.stream.cut_at_ns is not None and e.end_ns > now_ns for e in self._in_flight)
            if flush:
                self._stop_in_flight(now_ns)
            if targets:
                self.stats.interruptions += 1
                self.stats.streams_cut += len(targets)
            return CutOutcome(tuple(self._state(s, now_ns) for s in targets), flush)

    def pause(self, stream_id: str, now_ns: int) -> tuple[PlaybackState | None, bool]:
        """Hold `stream_id` where it is: (its state, or None if it is not playing or queued here;
        whether the sink must drop what it holds). Replies behind it wait."""
        with self._lock:
            stream = self._known(stream_id)
            if stream is None or stream.paused_at_ns is not None or self._finished(stream, now_ns):
                return (None if stream is None else self._state(stream, now_ns)), False
            stream.paused_at_ns = now_ns
            flush = any(e.stream is stream and e.end_ns > now_ns for e in self._in_flight)
            if flush:
                self._stop_in_flight(now_ns)
            if stream in self._streams:  # it goes first when resumed, before replies queued behind it
                self._streams.remove(stream)
            self._streams.appendleft(stream)
            self._current = stream
            self.stats.pauses += 1
            return self._state(stream, now_ns), flush

    def resume(self, stream_id: str, now_ns: int) -> PlaybackState | None:
        """Go on with a paused `stream_id` from where it stopped (None: no such paused reply)."""
        with self._lock:
            stream = self._known(stream_id)
            if stream is None or stream.paused_at_ns is None:
                return None
            stream.paused_at_ns = None
            self.stats.resumes += 1
            return self._state(stream, now_ns)

    def expire_pauses(self, max_pause_ns: int, now_ns: int) -> CutOutcome:
        """Cut every reply paused for longer than `max_pause_ns`."""
        with self._lock:
            expired = [
                s.stream_id
                for s in self._streams
                if s.paused_at_ns is not None and now_ns - s.paused_at_ns > max_pause_ns
            ]
            self.stats.pauses_expired += len(expired)
        cut: list[PlaybackState] = []
        flush = False
        for stream_id in expired:
            outcome = self.interrupt(Cut(stream_id, reason="pause expired"), now_ns)
            cut.extend(outcome.cut)
            flush = flush or outcome.flush_sink
        return CutOutcome(tuple(cut), flush)

    def pause_deadline_ns(self, max_pause_ns: int) -> int | None:
        """When the oldest pause expires (None: nothing paused)."""
        with self._lock:
            paused = [s.paused_at_ns for s in self._streams if s.paused_at_ns is not None]
            return min(paused) + max_pause_ns if paused else None

    def _known(self, stream_id: str) -> _Stream | None:
        """The reply `stream_id` if it is queued or playing and was not cut."""
        if not stream_id:
            return None
        for stream in (*self._streams, self._current, self._pending, *(e.stream for e in self._in_flight)):
            if stream is not None and stream.stream_id == stream_id and stream.cut_at_ns is None:
                return stream
        return None

    def _stop_in_flight(self, now_ns: int) -> None:
        """The sink drops everything from now on: cut replies lose their rest, kept replies get
        theirs back at the front of their queue (a device may hold several blocks)."""
        kept: list[tuple[_Stream, Int16Array]] = []
        for entry in self._in_flight:
            heard = samples_played_by(entry.start_ns, len(entry.pcm), self.sample_rate, now_ns)
            stream = entry.stream
            if heard < len(entry.pcm) and stream.cut_at_ns is None:
                stream.committed -= len(entry.pcm) - heard
                kept.append((stream, entry.pcm[heard:]))
            stream.play_end_ns = min(stream.play_end_ns, max(entry.start_ns, now_ns))
        for stream, rest in reversed(kept):
            self._requeue(stream, rest)
            if stream is self._pending:
                stream.requeued_ahead += 1
        self._in_flight.clear()
        self._play_end_ns = min(self._play_end_ns, now_ns)

    # -- what is going on -------------------------------------------------------------------

    def playing_until_ns(self) -> int:
        with self._lock:
            return self._play_end_ns

    def speaking(self, now_ns: int) -> bool:
        with self._lock:
            return self._speaking(now_ns)

    def _speaking(self, now_ns: int) -> bool:
        pending = self._pending is not None and self._pending.cut_at_ns is None
        if self._streams and self._streams[0].paused_at_ns is not None:
            return now_ns < self._play_end_ns  # held: nothing more sounds until it is resumed
        return now_ns < self._play_end_ns or self._queued_total > 0 or pending

    def _played(self, stream: _Stream, now_ns: int) -> int:
        if stream.cut_at_ns is not None:
            return stream.frozen_played
        unplayed = 0
        for entry in reversed(self._in_flight):  # in play order: stop at the first one over
            if entry.end_ns <= now_ns:
                break
            if entry.stream is stream:
                heard = samples_played_by(entry.start_ns, len(entry.pcm), self.sample_rate, now_ns)
                unplayed += len(entry.pcm) - heard
        return stream.committed - unplayed

    def _finished(self, stream: _Stream, now_ns: int) -> bool:
        return (
            stream.ended
            and stream.cut_at_ns is None
            and stream.paused_at_ns is None
            and stream.queued == 0
            and stream is not self._pending
            and now_ns >= stream.play_end_ns
        )

    def _state(self, stream: _Stream, now_ns: int) -> PlaybackState:
        dry = stream.queued == 0 and stream is not self._pending and now_ns >= stream.play_end_ns
        return PlaybackState(
            stream.stream_id,
            self._ms(self._played(stream, now_ns)),
            self._ms(stream.queued),
            self._speaking(now_ns),
            self._finished(stream, now_ns),
            stream.cut_at_ns is not None,
            dry and stream.started and not stream.ended and stream.cut_at_ns is None,
            stream.paused_at_ns is not None and stream.cut_at_ns is None,
        )

    def status(self, now_ns: int) -> PlaybackState:
        with self._lock:
            if self._current is None:
                return PlaybackState("", 0, 0, self._speaking(now_ns), False, False, False)
            state = self._state(self._current, now_ns)
            if state.finished:
                self._current.end_reported = True
            return state


ErrorHandler = Callable[[BaseException], None]


def _log_error(error: BaseException) -> None:
    _LOG.error("player loop failed: %s: %s", type(error).__name__, error, exc_info=error)


class PlayerLoop:
    """Feeds the sink from the engine on its own, supervised thread and reports what happened.

    `on_played(block, start_ns)` gets every block the sink accepted (the AEC reference);
    `on_change()` is called when the reported state changes (reply, speaking, finished, starved,
    interrupted, paused); `on_expired(outcome)` when paused replies were cut for waiting longer
    than `max_pause_ns`. An exception anywhere in the loop (sink, callbacks) is passed to
    `on_error`, counted in `errors`, and the loop goes on after a short, growing pause.
    """

    def __init__(
        self,
        engine: PlaybackEngine,
        sink: AudioSink,
        on_played: Callable[[PlayBlock, int], None],
        on_change: Callable[[], None],
        clock_ns: Callable[[], int] = time.time_ns,
        idle_poll_s: float = 0.005,
        on_error: ErrorHandler = _log_error,
        max_pause_ns: int = 5 * NS_PER_S,
        on_expired: Callable[[CutOutcome], None] = lambda outcome: None,
        on_retired: Callable[[tuple[PlaybackState, ...]], None] = lambda states: None,
    ) -> None:
        self.engine = engine
        self.sink = sink
        self.clock_ns = clock_ns
        self.errors = 0
        self._on_played = on_played
        self._on_change = on_change
        self._on_error = on_error
        self._idle_poll_s = idle_poll_s
        self._max_pause_ns = max_pause_ns
        self._on_expired = on_expired
        self._on_retired = on_retired
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._cancel = threading.Event()  # set by interrupt/stop: the block waiting for the sink is void
        # Held while a block goes into the sink and is committed, and while an interruption
        # cuts: so a cut always sees every block the sink took, and played_ms is exact.
        self._handoff = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="player", daemon=True)
        self._reported: tuple[object, ...] | None = None
        self._backoff_s = ERROR_BACKOFF_S[0]
        self._stopped = False

    def start(self) -> None:
        self._thread.start()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def wake(self) -> None:
        """New audio queued: don't wait for the idle poll."""
        self._wake.set()

    def interrupt(self, cut: Cut) -> CutOutcome:
        self._cancel.set()  # a sink wait in progress returns at once, so the handoff is free soon
        with self._handoff:
            now = self.clock_ns()
            outcome = self.engine.interrupt(cut, now)
            if outcome.flush_sink:
                self.sink.flush(now)
            self._cancel.clear()
        self._wake.set()
        return outcome

    def pause(self, stream_id: str) -> PlaybackState | None:
        """Hold `stream_id` at once (the sink drops what it holds of it); None: not here."""
        self._cancel.set()
        with self._handoff:
            now = self.clock_ns()
            state, flush = self.engine.pause(stream_id, now)
            if flush:
                self.sink.flush(now)
            self._cancel.clear()
        self._wake.set()
        return state

    def resume(self, stream_id: str) -> PlaybackState | None:
        state = self.engine.resume(stream_id, self.clock_ns())
        self._wake.set()
        return state

    def stop(self) -> CutOutcome:
        """Stop playing (everything still playing or queued is cut) and close the sink."""
        if self._stopped:
            return CutOutcome((), False)
        self._stopped = True
        self._stop.set()
        self._cancel.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        now = self.clock_ns()
        outcome = self.engine.interrupt(Cut(reason="shutdown"), now)
        if outcome.flush_sink:
            self.sink.flush(now)
        self.sink.close()
        return outcome

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._serve()
            except Exception as error:  # supervise: report, keep state consistent, go on
                self.errors += 1
                self.engine.drop_pending()
                self._report_error(error)
                self._stop.wait(self._backoff_s)
                self._backoff_s = min(self._backoff_s * 2, ERROR_BACKOFF_S[1])

    def _report_error(self, error: BaseException) -> None:
        try:
            self._on_error(error)
        except Exception:  # the reporter itself failed: the standard log still has it
            _LOG.exception("player loop failed and so did its error handler")

    def _serve(self) -> None:
        while not self._stop.is_set():
            block = self.engine.next_block()
            if block is None:
                self._expire_pauses()
                self._report_changes()
                self._wait_idle()
                continue
            with self._handoff:
                start_ns = self.sink.play(block.pcm, self._cancel) if self.engine.wants(block) else None
                if start_ns is None:  # cut, or an interruption is waiting: give it back
                    self.engine.give_back(block)
                    continue
                self.engine.commit(block, start_ns)
            self._backoff_s = ERROR_BACKOFF_S[0]
            self._on_played(block, start_ns)
            self._report_changes()

    def _expire_pauses(self) -> None:
        deadline = self.engine.pause_deadline_ns(self._max_pause_ns)
        if deadline is None or self.clock_ns() < deadline:
            return
        with self._handoff:
            now = self.clock_ns()
            outcome = self.engine.expire_pauses(self._max_pause_ns, now)
            if outcome.flush_sink:
                self.sink.flush(now)
        if outcome.cut:
            self._on_expired(outcome)

    def _report_changes(self) -> None:
        retired = self.engine.take_retired(self.clock_ns())
        if retired:
            self._on_retired(retired)
        state = self.engine.status(self.clock_ns())
        key = (
            state.stream_id,
            state.speaking,
            state.finished,
            state.interrupted,
            state.starved,
            state.paused,
        )
        if key != self._reported:
            self._reported = key
            self._on_change()

    def _wait_idle(self) -> None:
        # While the last block plays out, wake at its end so speaking goes False on time. With
        # nothing playing, only new audio or a cut (both set _wake) changes anything: sleep long
        # (a 20 ms poll cost the idle player ~0.5 % of a core).
        now = self.clock_ns()
        remaining_s = (self.engine.playing_until_ns() - now) / NS_PER_S
        timeout = min(self._idle_poll_s * 4, remaining_s) if remaining_s > 0 else IDLE_WAIT_S
        pause_deadline = self.engine.pause_deadline_ns(self._max_pause_ns)
        if pause_deadline is not None:  # wake when a pause expires
            timeout = min(timeout, (pause_deadline - now) / NS_PER_S)
        self._wake.wait(max(timeout, 0.001))
        self._wake.clear()
