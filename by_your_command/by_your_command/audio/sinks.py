"""Where the player's blocks go: a PortAudio output device, or a WAV file paced like one.

A sink holds at most the block that is playing: `play` waits until the previous block has ended,
so an interruption (the `cancel` event) can void the next block before anyone hears it, and
`flush(at_ns)` drops what the block playing would still have sounded from `at_ns` on.
"""

from __future__ import annotations

import logging
import threading
import time
import wave
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from by_your_command.audio.devices import AudioDeviceError
from by_your_command.audio.pcm import Int16Array

_LOG = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
CONTINUOUS_SLACK_NS = 5_000_000  # a block starting this late after the previous one is a gap


def samples_played_by(start_ns: int, length: int, sample_rate: int, at_ns: int) -> int:
    """How many samples of a block of `length` that started at `start_ns` have sounded by `at_ns`.

    The one formula the player's bookkeeping and the sinks share, so `played_ms` and what a sink
    really let out agree to the sample."""
    if at_ns <= start_ns:
        return 0
    return min(length, (at_ns - start_ns) * sample_rate // NS_PER_S)


class AudioSink(Protocol):
    sample_rate: int

    def play(self, pcm: Int16Array, cancel: threading.Event) -> int | None:
        """Block until `pcm` starts playing; return that time (ns, time.time_ns clock), or None
        if `cancel` was set first (then nothing of `pcm` is played)."""

    def flush(self, at_ns: int) -> None:
        """Drop whatever the sink would still play from `at_ns` on (interruption)."""

    def close(self) -> None: ...


class WavSink:
    """Writes played audio to a mono 16-bit WAV file.

    With realtime=True it takes one block per block duration, like a device, and holds the block
    that is playing until it has ended: `flush(at_ns)` writes only the part that had sounded by
    then, so the file is exactly what a listener heard. With realtime=False it writes every block
    at once (tests that only need the samples)."""

    def __init__(self, path: str | Path, sample_rate: int, realtime: bool = True) -> None:
        self.sample_rate = sample_rate
        self.realtime = realtime
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("wb")
        self._wav = wave.open(self._file, "wb")
        self._wav.setnchannels(1)
        self._wav.setsampwidth(2)
        self._wav.setframerate(sample_rate)
        self._lock = threading.Lock()
        self._next_free_ns = 0  # when the block now playing ends
        self._playing: tuple[int, Int16Array] | None = None  # (start, samples) not yet written
        self._closed = False
        self.samples_written = 0

    def play(self, pcm: Int16Array, cancel: threading.Event) -> int | None:
        if self.realtime:
            wait_s = (self._next_free_ns - time.time_ns()) / NS_PER_S
            if wait_s > 0 and cancel.wait(wait_s):
                return None
        with self._lock:
            if cancel.is_set() or self._closed:
                return None
            now = time.time_ns()
            start = self._next_free_ns if 0 <= now - self._next_free_ns <= CONTINUOUS_SLACK_NS else now
            self._write_playing(None)  # the previous block has ended: all of it was heard
            if self.realtime:
                self._playing = (start, np.ascontiguousarray(pcm, dtype=np.int16))
            else:
                self._write(pcm)
            self._next_free_ns = start + len(pcm) * NS_PER_S // self.sample_rate
            return start

    def flush(self, at_ns: int) -> None:
        with self._lock:
            if self._playing is not None:
                start = self._playing[0]
                self._write_playing(at_ns)
                self._next_free_ns = min(self._next_free_ns, max(start, at_ns))

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._write_playing(time.time_ns())  # stopped mid-block: only what had sounded
            self._closed = True
            self._wav.close()
            self._file.close()

    def _write_playing(self, until_ns: int | None) -> None:
        """Write the held block, all of it (until_ns None) or what had sounded by `until_ns`."""
        if self._playing is None:
            return
        start, pcm = self._playing
        self._playing = None
        count = (
            len(pcm) if until_ns is None else samples_played_by(start, len(pcm), self.sample_rate, until_ns)
        )
        self._write(pcm[:count])

    def _write(self, pcm: Int16Array) -> None:
        if len(pcm) == 0:
            return
        self._wav.writeframes(np.ascontiguousarray(pcm, dtype="<i2").tobytes())
        self._file.flush()  # readers (tests) may look while we play
        self.samples_written += len(pcm)


class DeviceSink:
    """PortAudio output through sounddevice, with a device buffer of about one block."""

    def __init__(self, device: int | None, sample_rate: int, block_samples: int) -> None:
        import sounddevice as sd

        self.sample_rate = sample_rate
        self._sd: Any = sd
        try:
            self._stream: Any = sd.OutputStream(
                samplerate=sample_rate,
                channels=1,
                dtype="int16",
                device=device,
                blocksize=block_samples,
                latency="low",
            )
            self._stream.start()
        except sd.PortAudioError as error:
            raise AudioDeviceError(
                f"cannot open output device {device} at {sample_rate} Hz: {error}"
            ) from error
        self._lock = threading.Lock()
        self.underflows = 0

    def play(self, pcm: Int16Array, cancel: threading.Event) -> int | None:
        if cancel.is_set():
            return None
        with self._lock:
            start = time.time_ns() + int(float(self._stream.latency) * NS_PER_S)
            underflowed = self._stream.write(np.ascontiguousarray(pcm, dtype=np.int16).reshape(-1, 1))
        if underflowed:
            self.underflows += 1
        return start

    def flush(self, at_ns: int) -> None:
        # abort drops the device buffer at once (stop would play it out); called right at at_ns
        with self._lock:
            self._stream.abort()
            self._stream.start()

    def close(self) -> None:
        with self._lock:
            self._stream.abort()
            self._stream.close()
