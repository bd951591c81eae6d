"""Echo control: AEC3 echo reduction (dB) on a synthetic room, and CPU cost per 10 ms frame of
aec vs gate vs pass-through, all measured in this run.

    scripts/run.sh python bench/bench_aec.py
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "by_your_command" / "test"))

from audio_io.synthetic_room import (  # type: ignore[import-not-found]  # noqa: E402
    Room,
    energy_db,
    recorded_speech,
    speech_like,
)

from by_your_command.audio.echo import EchoConfig, EchoController  # noqa: E402
from by_your_command.audio.pcm import Int16Array, float_to_int16  # noqa: E402

RATE = 16000
BLOCK = 512
SECONDS = 10.0
CONVERGED_FROM_S = 3.0
T0 = 1_700_000_000 * 1_000_000_000


def run(mode: str, far: Int16Array, mic: Int16Array) -> tuple[Int16Array, float, int]:
    """(output, seconds of CPU spent in the controller, 10 ms frames processed)."""
    echo = EchoController(EchoConfig(mode=mode))
    outs = []
    spent = 0.0
    for k in range(0, len(mic) // BLOCK * BLOCK, BLOCK):
        start = T0 + k * 1_000_000_000 // RATE
        began = time.process_time()
        echo.add_reference(far[k : k + BLOCK], RATE, 1, start)
        out = echo.process(mic[k : k + BLOCK], start, start)
        spent += time.process_time() - began
        if out is not None:
            outs.append(out.pcm)
    frames = len(mic) // BLOCK * BLOCK // (RATE // 100)
    return (np.concatenate(outs) if outs else np.zeros(0, dtype=np.int16)), spent, frames


def main() -> int:
    rng = np.random.default_rng(7)
    signals = {
        "speech": recorded_speech(SECONDS, RATE),
        "buzz_like": speech_like(SECONDS, RATE, seed=11),
        "noise": float_to_int16(0.2 * rng.standard_normal(int(SECONDS * RATE))),
    }
    rooms = {
        "delay80": Room(delay_ms=80),
        "delay150": Room(delay_ms=150),
        "delay150_rev": Room(delay_ms=150, reverb_ms=250, reverb_gain=0.4),
    }
    rows = []
    for signal_name, far in signals.items():
        for room_name, room in rooms.items():
            mic = room.echo(far, RATE)
            out, spent, frames = run("aec", far, mic)
            lo = int(CONVERGED_FROM_S * RATE)
            reduction = energy_db(mic[lo : len(out)]) - energy_db(out[lo:])
            per_second = [
                energy_db(mic[s : s + RATE]) - energy_db(out[s : s + RATE])
                for s in range(lo, len(out) - RATE + 1, RATE)
            ]
            figure = {
                "bench": "aec",
                "figure": "echo_reduction_db",
                "signal": signal_name,
                "room": room_name,
                "value": round(reduction, 1),
                "median_per_second_db": round(statistics.median(per_second), 1),
                "unit": "dB",
            }
            print(json.dumps(figure))
            rows.append(
                (
                    f"echo reduction {signal_name}/{room_name}",
                    f"{reduction:.1f} dB",
                    f"median/s {statistics.median(per_second):.1f} dB",
                )
            )
    far = signals["speech"]
    mic = Room().echo(far, RATE)
    costs = {}
    for mode in ("external", "gate", "aec"):
        samples = []
        for _ in range(3):
            _, spent, frames = run(mode, far, mic)
            samples.append(spent / frames * 1e6)
        costs[mode] = statistics.median(samples)
    for mode, cost in costs.items():
        ratio = cost / costs["external"]
        print(
            json.dumps(
                {
                    "bench": "aec",
                    "figure": "cpu_per_10ms_frame_us",
                    "mode": mode,
                    "value": round(cost, 2),
                    "ratio_vs_external": round(ratio, 1),
                    "unit": "us",
                }
            )
        )
        rows.append(
            (
                f"CPU per 10 ms frame, {mode}",
                f"{cost:.1f} us",
                f"{ratio:.1f}x pass-through, {cost / 10_000 * 100:.2f}% of one core",
            )
        )
    width = max(len(r[0]) for r in rows)
    print()
    for name, value, note in rows:
        print(f"{name:<{width}}  {value:>10}  {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
