"""Player: blocks, resampling, played_ms, interruption latency, assistant_speaking timing."""

from __future__ import annotations

import threading
import time
import wave
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from byc_testing import wait_for

from by_your_command.audio.pcm import StreamResampler, read_wav, resample
from by_your_command.audio.player import (
    PlaybackEngine,
    PlayBlock,
    PlayerConfig,
    PlayerLoop,
)
from by_your_command.audio.sinks import WavSink

RATE = 16000
MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000


def tone(seconds: float, rate: int, freq: float = 440.0) -> np.ndarray:
    t = np.arange(int(seconds * rate)) / rate
    return np.rint(8000 * np.sin(2 * np.pi * freq * t)).astype(np.int16)


@pytest.mark.unit
@pytest.mark.parametrize(
    "kwargs",
    [{"block_ms": 41}, {"block_ms": 0}, {"sink": "wav"}, {"sink": "pipe"}, {"sample_rate": 0}],
)
def test_bad_player_config_is_a_clear_error(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        PlayerConfig(**kwargs)  # type: ignore[arg-type]


@pytest.mark.unit
@pytest.mark.parametrize(("src", "dst"), [(24000, 16000), (16000, 48000), (44100, 16000), (16000, 16000)])
def test_stream_resampler_matches_one_shot_resampling(src: int, dst: int) -> None:
    signal = tone(1.0, src, 300.0)
    resampler = StreamResampler(src, dst)
    rng = np.random.default_rng(0)
    parts, pos = [], 0
    while pos < len(signal):  # ragged chunks, as agents send them
        size = int(rng.integers(50, 2000))
        parts.append(resampler.push(signal[pos : pos + size]))
        pos += size
    parts.append(resampler.flush())
    streamed = np.concatenate(parts).astype(np.float64)
    whole = resample(signal, src, dst).astype(np.float64)
    assert abs(len(streamed) - len(whole)) <= 1
    n = min(len(streamed), len(whole))
    error = np.abs(streamed[100 : n - 100] - whole[100 : n - 100])
    assert error.max() <= 40  # of 8000 peak: no clicks at chunk edges


@pytest.mark.unit
def test_engine_resamples_24k_to_the_sink_rate_and_keeps_duration() -> None:
    engine = PlaybackEngine(RATE, block_samples=320, max_queue_samples=10 * RATE)
    voice = tone(1.0, 24000)
    for k in range(0, len(voice), 2400):  # 100 ms chunks at 24 kHz
        engine.enqueue("r1", voice[k : k + 2400], 24000, 1)
    blocks = []
    while (block := engine.next_block()) is not None:
        assert len(block.pcm) <= 320 and block.stream_id == "r1"
        blocks.append(block.pcm)
    played = np.concatenate(blocks)
    assert abs(len(played) - RATE) <= 2  # one second at 16 kHz
    spectrum = np.abs(np.fft.rfft(played.astype(np.float64)))
    assert abs(np.argmax(spectrum) * RATE / len(played) - 440) < 3


@pytest.mark.unit
def test_played_ms_counts_only_audio_that_has_played() -> None:
    engine = PlaybackEngine(RATE, block_samples=320, max_queue_samples=10 * RATE)
    engine.enqueue("r1", tone(0.5, RATE), RATE, 1)
    now = T0
    for _ in range(10):  # 10 blocks of 20 ms, back to back
        block = engine.next_block()
        assert block is not None
        engine.commit(block, now)
        now += 20 * MS
    mid = engine.status(now - 10 * MS)  # halfway through the 10th block
    assert mid.stream_id == "r1" and mid.speaking
    assert mid.played_ms == 190
    assert mid.queued_ms == 300
    done = engine.status(now)
    assert done.played_ms == 200 and not done.finished  # 300 ms still queued


@pytest.mark.unit
def test_status_finished_and_not_speaking_after_the_last_block() -> None:
    engine = PlaybackEngine(RATE, block_samples=320, max_queue_samples=RATE)
    engine.enqueue("r1", tone(0.04, RATE), RATE, 1)
    now = T0
    while (block := engine.next_block()) is not None:
        engine.commit(block, now)
        now += 20 * MS
    assert engine.speaking(now - 1)
    state = engine.status(now)
    assert (state.played_ms, state.queued_ms, state.speaking, state.finished) == (40, 0, False, True)


@pytest.mark.unit
def test_interrupt_flushes_every_response_and_drops_their_late_chunks() -> None:
    engine = PlaybackEngine(RATE, block_samples=320, max_queue_samples=10 * RATE)
    engine.enqueue("r1", tone(1.0, RATE), RATE, 1)
    engine.enqueue("r2", tone(1.0, RATE), RATE, 1)
    block = engine.next_block()
    assert block is not None
    engine.commit(block, T0)
    assert engine.interrupt(T0 + 5 * MS)
    assert engine.cancel.is_set()
    state = engine.status(T0 + 20 * MS)
    assert state.interrupted and not state.finished and state.queued_ms == 0 and state.played_ms == 20
    engine.enqueue("r1", tone(0.1, RATE), RATE, 1)  # still in flight from the agent
    assert engine.next_block() is None
    assert engine.stats.chunks_dropped_interrupted == 1
    engine.enqueue("r3", tone(0.1, RATE), RATE, 1)  # the next response plays
    assert (b := engine.next_block()) is not None and b.stream_id == "r3"


@pytest.mark.unit
def test_responses_play_in_order_and_bad_chunks_are_rejected_loudly() -> None:
    engine = PlaybackEngine(RATE, block_samples=800, max_queue_samples=RATE)
    engine.enqueue("a", tone(0.05, RATE), RATE, 1)
    engine.enqueue("b", tone(0.05, RATE), RATE, 1)
    order = []
    while (block := engine.next_block()) is not None:
        order.append(block.stream_id)
    assert order == ["a", "b"]
    with pytest.raises(ValueError):
        engine.enqueue("c", np.zeros(3, dtype=np.int16), RATE, 2)  # not whole stereo frames
    with pytest.raises(ValueError):
        engine.enqueue("c", np.zeros(4, dtype=np.int16), 0, 1)
    assert engine.stats.chunks_rejected == 2


@pytest.mark.unit
def test_queue_overflow_is_counted() -> None:
    engine = PlaybackEngine(RATE, block_samples=320, max_queue_samples=RATE // 10)
    engine.enqueue("r", tone(0.5, RATE), RATE, 1)
    assert engine.stats.samples_dropped_overflow == int(0.4 * RATE)


class Recorder:
    def __init__(self) -> None:
        self.played: list[tuple[PlayBlock, int]] = []
        self.changes = 0

    def on_played(self, block: PlayBlock, start_ns: int) -> None:
        self.played.append((block, start_ns))

    def on_change(self) -> None:
        self.changes += 1


def _loop(
    tmp_path: Path,
    realtime: bool,
    block_ms: int = 20,
    on_change: Callable[[PlaybackEngine], None] | None = None,
) -> tuple[PlayerLoop, Recorder, WavSink]:
    block = RATE * block_ms // 1000
    engine = PlaybackEngine(RATE, block, 60 * RATE)
    sink = WavSink(tmp_path / "out.wav", RATE, realtime=realtime)
    recorder = Recorder()

    def changed() -> None:
        recorder.on_change()
        if on_change is not None:
            on_change(engine)

    return PlayerLoop(engine, sink, recorder.on_played, changed), recorder, sink


@pytest.mark.unit
def test_loop_drains_to_the_wav_sink_without_realtime(tmp_path: Path) -> None:
    loop, recorder, sink = _loop(tmp_path, realtime=False)
    loop.start()
    voice = tone(0.5, 24000)
    loop.engine.enqueue("r1", voice, 24000, 1)
    loop.wake()
    wait_for(lambda: sink.samples_written >= RATE // 2 - 2, timeout=5, what="the response written")
    loop.stop()
    pcm, rate, channels = read_wav(tmp_path / "out.wav")
    assert (rate, channels) == (RATE, 1) and abs(len(pcm) - RATE // 2) <= 2
    assert all(len(b.pcm) <= 320 for b, _ in recorder.played)


@pytest.mark.unit
def test_realtime_interruption_silences_within_one_block_and_speaking_drops_fast(tmp_path: Path) -> None:
    speaking_false_at: list[int] = []

    def on_change(engine: PlaybackEngine) -> None:
        if not engine.speaking(time.time_ns()):
            speaking_false_at.append(time.time_ns())

    loop, recorder, sink = _loop(tmp_path, realtime=True, block_ms=20, on_change=on_change)
    loop.start()
    loop.engine.enqueue("r1", tone(3.0, RATE), RATE, 1)
    loop.wake()
    wait_for(lambda: len(recorder.played) >= 10, timeout=5, what="200 ms played")
    interrupted_at = time.time_ns()
    assert loop.interrupt()
    wait_for(lambda: speaking_false_at, timeout=2, what="assistant_speaking False")
    last_block, last_start = recorder.played[-1]
    last_sample_end = last_start + len(last_block.pcm) * 1_000_000_000 // RATE
    latency_ms = (last_sample_end - interrupted_at) / 1e6
    print(f"interruption -> last sample played: {latency_ms:.1f} ms (block 20 ms)")
    assert latency_ms <= 20 + 5
    assert (speaking_false_at[0] - last_sample_end) / 1e6 < 100
    state = loop.engine.status(time.time_ns())
    assert state.interrupted and 180 <= state.played_ms <= 3000 - 1000
    loop.stop()
    with wave.open(str(tmp_path / "out.wav")) as wav:
        assert wav.getnframes() == sum(len(b.pcm) for b, _ in recorder.played) < 3 * RATE


@pytest.mark.unit
def test_realtime_speaking_goes_false_soon_after_the_last_sample(tmp_path: Path) -> None:
    ended = threading.Event()
    ended_at: list[int] = []

    def on_change(engine: PlaybackEngine) -> None:
        if engine.stats.blocks_played and not engine.speaking(time.time_ns()):
            ended_at.append(time.time_ns())
            ended.set()

    loop, recorder, _ = _loop(tmp_path, realtime=True, on_change=on_change)
    loop.start()
    loop.engine.enqueue("r1", tone(0.3, RATE), RATE, 1)
    loop.wake()
    assert ended.wait(5)
    loop.stop()
    last_block, last_start = recorder.played[-1]
    end = last_start + len(last_block.pcm) * 1_000_000_000 // RATE
    delay_ms = (ended_at[0] - end) / 1e6
    print(f"assistant_speaking False {delay_ms:.1f} ms after the last sample")
    assert 0 <= delay_ms < 100
    starts = [start for _, start in recorder.played]
    assert (starts[-1] - starts[0]) / 1e6 == pytest.approx(280, abs=15)  # paced in real time
