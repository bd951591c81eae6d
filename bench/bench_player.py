"""Player timings, each against a baseline measured in the same run:

- interruption -> silence: from `PlayerLoop.interrupt` to the end of the last sample the sink
  played (the WAV sink cuts its block at the interruption, as a device's abort does), median/p99
  over many trials, as a multiple of the block duration (the design bound: at most one block);
- assistant_speaking False after the last sample of a reply that played to its end;
- chunk arrival -> status: from `enqueue` of a reply's first chunk (loop idle) to the state change
  that publishes `speaking` True, against a bare thread hand-off (Event.set -> waiter running);
- CPU per 100 ms chunk through the engine (validate, resample, queue, hand out, commit) against
  the resampler alone on the same chunks.

Uses the real player loop with a real-time paced WAV sink (no sound card needed).

    scripts/run.sh python bench/bench_player.py
"""

from __future__ import annotations

import json
import random
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from by_your_command.audio.pcm import StreamResampler
from by_your_command.audio.player import Cut, PlaybackEngine, PlayBlock, PlayerLoop, VoiceChunk
from by_your_command.audio.sinks import WavSink

RATE = 24000
TRIALS = 20
BLOCKS_MS = (10, 20, 40)
ARRIVAL_TRIALS = 60
CPU_CHUNKS = 300
NS_PER_MS = 1_000_000


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


def emit(figure: dict[str, object]) -> None:
    print(json.dumps({"bench": "player", **figure}))


def interruption_trial(block_ms: int, directory: Path, index: int, rng: random.Random) -> tuple[float, float]:
    """(interruption -> last sample end, reply end -> speaking False), both in ms."""
    engine = PlaybackEngine(RATE, RATE * block_ms // 1000, 60 * RATE)
    sink = WavSink(directory / f"trial_{block_ms}_{index}.wav", RATE, realtime=True)
    played: list[tuple[PlayBlock, int]] = []
    silent = threading.Event()
    silent_at: list[int] = []

    def on_change() -> None:
        if played and not engine.speaking(time.time_ns()) and not silent.is_set():
            silent_at.append(time.time_ns())
            silent.set()

    loop = PlayerLoop(engine, sink, lambda block, start: played.append((block, start)), on_change)
    loop.start()
    engine.enqueue(VoiceChunk("response", np.full(RATE * 2, 1000, dtype=np.int16), RATE), time.time_ns())
    loop.wake()
    time.sleep(rng.uniform(0.08, 0.2))  # interrupt somewhere inside a block, at random
    interrupted_at = time.time_ns()
    loop.interrupt(Cut("response", reason="bench"))
    silent.wait(2.0)
    loop.stop()
    # The file holds exactly what was heard, from the first block's start on, without gaps.
    heard_ns = sink.samples_written * 1_000_000_000 // RATE
    latency = max(0, played[0][1] + heard_ns - interrupted_at) / NS_PER_MS
    # Hangover: a short reply that plays to its end_of_stream.
    engine = PlaybackEngine(RATE, RATE * block_ms // 1000, 60 * RATE)
    sink = WavSink(directory / f"end_{block_ms}_{index}.wav", RATE, realtime=True)
    played, silent, silent_at = [], threading.Event(), []
    loop = PlayerLoop(engine, sink, lambda block, start: played.append((block, start)), on_change)
    loop.start()
    engine.enqueue(
        VoiceChunk("r", np.full(RATE // 10, 1000, dtype=np.int16), RATE, end_of_stream=True), time.time_ns()
    )
    loop.wake()
    silent.wait(2.0)
    loop.stop()
    last_block, last_start = played[-1]
    last_end = last_start + len(last_block.pcm) * 1_000_000_000 // RATE
    return latency, (silent_at[0] - last_end) / NS_PER_MS


def handoff_latency_ms(trials: int) -> list[float]:
    """Baseline: Event.set in one thread -> the waiting thread runs."""
    go, done = threading.Event(), threading.Event()
    woke: list[int] = []

    def waiter() -> None:
        for _ in range(trials):
            go.wait()
            go.clear()
            woke.append(time.perf_counter_ns())
            done.set()

    thread = threading.Thread(target=waiter)
    thread.start()
    latencies = []
    for _ in range(trials):
        done.clear()
        time.sleep(0.002)  # let the waiter block again
        sent = time.perf_counter_ns()
        go.set()
        done.wait()
        latencies.append((woke[-1] - sent) / NS_PER_MS)
    thread.join()
    return latencies


def arrival_to_status_ms(directory: Path, trials: int) -> list[float]:
    engine = PlaybackEngine(RATE, RATE // 50, 60 * RATE)
    sink = WavSink(directory / "arrival.wav", RATE, realtime=True)
    speaking_at: list[int] = []
    finished = threading.Event()

    def on_change() -> None:
        state = engine.status(time.time_ns())
        if state.speaking and state.stream_id:
            speaking_at.append(time.perf_counter_ns())
        if state.finished:
            finished.set()

    loop = PlayerLoop(engine, sink, lambda block, start: None, on_change)
    loop.start()
    latencies = []
    reply = np.full(RATE // 50, 1000, dtype=np.int16)  # one 20 ms block
    for index in range(trials):
        finished.clear()
        before = len(speaking_at)
        time.sleep(0.002)  # the loop is idle, as when a reply's first chunk comes in
        sent = time.perf_counter_ns()
        engine.enqueue(VoiceChunk(f"r{index}", reply, RATE, end_of_stream=True), time.time_ns())
        loop.wake()
        finished.wait(2.0)
        if len(speaking_at) > before:
            latencies.append((speaking_at[before] - sent) / NS_PER_MS)
    loop.stop()
    return latencies


def cpu_per_chunk_us(source_rate: int) -> tuple[float, float]:
    """(engine, resampler alone) median µs per 100 ms chunk, sink at 24 kHz."""
    chunk = (np.random.default_rng(0).standard_normal(source_rate // 10) * 3000).astype(np.int16)
    engine = PlaybackEngine(RATE, RATE // 50, 600 * RATE)
    resampler = StreamResampler(source_rate, RATE)
    engine_us, alone_us = [], []
    now = time.time_ns()
    for _ in range(CPU_CHUNKS):
        start = time.perf_counter_ns()
        resampler.push(chunk)
        alone_us.append((time.perf_counter_ns() - start) / 1000)
        start = time.perf_counter_ns()
        engine.enqueue(VoiceChunk("cpu", chunk, source_rate), now)
        while (block := engine.next_block()) is not None:
            engine.commit(block, now)
            now += len(block.pcm) * 1_000_000_000 // RATE
        engine_us.append((time.perf_counter_ns() - start) / 1000)
    return statistics.median(engine_us), statistics.median(alone_us)


def main() -> int:
    rng = random.Random(1)
    rows: list[tuple[str, float, float | None, str]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for block_ms in BLOCKS_MS:
            latencies, hangovers = [], []
            for index in range(TRIALS):
                latency, hangover = interruption_trial(block_ms, Path(tmp), index, rng)
                latencies.append(latency)
                hangovers.append(hangover)
            median, p99 = statistics.median(latencies), percentile(latencies, 99)
            emit(
                {
                    "figure": "interruption_to_silence_ms",
                    "block_ms": block_ms,
                    "trials": TRIALS,
                    "median": round(median, 2),
                    "p99": round(p99, 2),
                    "baseline_block_ms": block_ms,
                    "median_ratio_vs_block": round(median / block_ms, 2),
                    "p99_ratio_vs_block": round(p99 / block_ms, 2),
                }
            )
            h_median, h_p99 = statistics.median(hangovers), percentile(hangovers, 99)
            emit(
                {
                    "figure": "speaking_false_after_last_sample_ms",
                    "block_ms": block_ms,
                    "median": round(h_median, 2),
                    "p99": round(h_p99, 2),
                    "baseline_block_ms": block_ms,
                    "median_ratio_vs_block": round(h_median / block_ms, 3),
                }
            )
            rows.append(
                (f"interrupt->silence, block {block_ms} ms", median, p99, f"{median / block_ms:.2f} blocks")
            )
            rows.append((f"speaking False after end, block {block_ms} ms", h_median, h_p99, "-"))
        arrival = arrival_to_status_ms(Path(tmp), ARRIVAL_TRIALS)
    handoff = handoff_latency_ms(ARRIVAL_TRIALS)
    a_median, h_median = statistics.median(arrival), statistics.median(handoff)
    emit(
        {
            "figure": "chunk_arrival_to_speaking_status_ms",
            "trials": len(arrival),
            "median": round(a_median, 3),
            "p99": round(percentile(arrival, 99), 3),
            "baseline": "thread_handoff_ms",
            "baseline_median": round(h_median, 3),
            "median_ratio_vs_baseline": round(a_median / h_median, 1),
        }
    )
    rows.append(
        (
            "chunk arrival -> speaking status",
            a_median,
            percentile(arrival, 99),
            f"{a_median / h_median:.1f}x hand-off",
        )
    )
    rows.append(("  baseline: thread hand-off", h_median, percentile(handoff, 99), "-"))
    for source_rate in (RATE, 16000):
        engine_us, alone_us = cpu_per_chunk_us(source_rate)
        emit(
            {
                "figure": "cpu_per_100ms_chunk_us",
                "source_rate": source_rate,
                "sink_rate": RATE,
                "median": round(engine_us, 1),
                "baseline": "resampler_alone_us",
                "baseline_median": round(alone_us, 1),
                "median_ratio_vs_baseline": round(engine_us / max(alone_us, 0.1), 2),
            }
        )
        rows.append(
            (
                f"engine CPU per 100 ms chunk {source_rate}->{RATE} (us)",
                engine_us,
                None,
                f"resampler alone {alone_us:.1f} us",
            )
        )
    print()
    print(f"{'figure':52s} {'median':>9s} {'p99':>9s}  vs baseline")
    for name, row_median, row_p99, versus in rows:
        p99_text = f"{row_p99:9.2f}" if row_p99 is not None else f"{'':9s}"
        print(f"{name:52s} {row_median:9.2f} {p99_text}  {versus}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
