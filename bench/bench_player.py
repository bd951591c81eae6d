"""Player interruption-to-silence latency: time from interruption_signal to the end of the last
sample the sink played, median/p99 over many trials, against the block duration (the design bound)
measured in the same run; plus how long assistant_speaking stays True after the last sample.

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

from by_your_command.audio.player import PlaybackEngine, PlayBlock, PlayerLoop
from by_your_command.audio.sinks import WavSink

RATE = 24000
TRIALS = 25
BLOCKS_MS = (10, 20, 40)
NS_PER_MS = 1_000_000


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


def trial(block_ms: int, directory: Path, index: int, rng: random.Random) -> tuple[float, float]:
    """(interruption -> last sample end, last sample end -> speaking False), both in ms."""
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
    engine.enqueue("response", np.full(RATE * 2, 1000, dtype=np.int16), RATE, 1)
    loop.wake()
    time.sleep(rng.uniform(0.08, 0.2))  # interrupt somewhere inside a block, at random
    interrupted_at = time.time_ns()
    loop.interrupt()
    silent.wait(2.0)
    loop.stop()
    last_block, last_start = played[-1]
    last_end = last_start + len(last_block.pcm) * 1_000_000_000 // RATE
    return max(0, last_end - interrupted_at) / NS_PER_MS, (silent_at[0] - last_end) / NS_PER_MS


def main() -> int:
    rng = random.Random(1)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for block_ms in BLOCKS_MS:
            latencies, hangovers = [], []
            for index in range(TRIALS):
                latency, hangover = trial(block_ms, Path(tmp), index, rng)
                latencies.append(latency)
                hangovers.append(hangover)
            median, p99 = statistics.median(latencies), percentile(latencies, 99)
            figure = {
                "bench": "player",
                "figure": "interruption_to_silence_ms",
                "block_ms": block_ms,
                "trials": TRIALS,
                "median": round(median, 2),
                "p99": round(p99, 2),
                "baseline_block_ms": block_ms,
                "median_ratio_vs_block": round(median / block_ms, 2),
                "p99_ratio_vs_block": round(p99 / block_ms, 2),
            }
            print(json.dumps(figure))
            speaking = {
                "bench": "player",
                "figure": "speaking_false_after_last_sample_ms",
                "block_ms": block_ms,
                "median": round(statistics.median(hangovers), 2),
                "p99": round(percentile(hangovers, 99), 2),
            }
            print(json.dumps(speaking))
            rows.append((block_ms, median, p99, statistics.median(hangovers), percentile(hangovers, 99)))
    print()
    print("block  interrupt->silence median / p99 (x block)   speaking False after last sample median / p99")
    for block_ms, median, p99, h_median, h_p99 in rows:
        print(
            f"{block_ms:3d} ms  {median:6.1f} / {p99:6.1f} ms "
            f"({median / block_ms:.2f} / {p99 / block_ms:.2f})          {h_median:6.1f} / {h_p99:6.1f} ms"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
