"""CPU of the safety stop spotter while the robot speaks, in aec mode (compute per second of audio).

In aec mode the spotter (by_your_command.safety, in silero_vad_node) hears the raw mic and, while
the robot plays and a second after, runs its own echo canceller (the linear aec engine and its
residual suppressor) on it, and decodes the played reference to know the robot's own words.
Here StopSpotter is fed as the node's worker feeds it (64 ms blocks, each reference block before
the mic block it belongs to) with a robot reply (espeak-ng, ~12 s, its echo at -20 dBFS at the
mic over -70 dBFS room noise), and its CPU time is read around the calls (time.process_time).
CPU % of one core = CPU seconds / seconds of audio: what it costs at real time, without the ROS
message overhead (the node receives audio_played in any case). Scenarios, same run, interleaved:

  silent      the baseline: the spotter with the robot silent (room noise only, no reference)
  speaking    the robot speaks: aec mode as shipped (stop_cancel_echo: true)
  no_cancel   the robot speaks, the spotter's echo cancellation off (its reference decoding stays)
  echo_alone  the spotter's echo controller alone on the same mic and reference (its share)
  reference   the reference decoding alone: the robot plays, its echo never reaches the mic
              (room noise), no cancellation (the spotter's own-voice marks)

usage: scripts/run.sh python bench/bench_spotter_cpu.py [--rounds 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "by_your_command" / "test"))

from audio_io.synthetic_room import ROBOT_REPLY, Room, at_level, espeak  # type: ignore[import-not-found]  # noqa: E402

from by_your_command.audio.echo import EchoConfig, EchoController  # noqa: E402
from by_your_command.audio.pcm import Int16Array, float_to_int16, rms_dbfs  # noqa: E402
from by_your_command.safety.config import StopConfig  # noqa: E402
from by_your_command.safety.spotter import ECHO_GUARD_MARGIN_DB, StopSpotter  # noqa: E402

RATE = 16000
BLOCK = 1024  # the shipped mic chunk (64 ms)
NS = 1_000_000_000
T0 = 1_700_000_000 * NS
LEAD_S, TAIL_S = 0.5, 1.5
ROOM = Room()
ECHO_DBFS = -20.0  # the robot's voice at the mic, RMS while it speaks (bench_safety_stop's)
NOISE = 10.0  # room noise RMS (-70 dBFS)


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    record = {"bench": "spotter_cpu", "figure": figure, "value": round(value, 3), "unit": unit}
    print(json.dumps({**record, **extra}), flush=True)


def scene() -> tuple[Int16Array, Int16Array, Int16Array, int, int]:
    """(mic while the robot speaks, played, mic in a silent room, first and last played sample)."""
    reply = at_level(espeak(ROBOT_REPLY, "en-gb", RATE), -18.0)
    lead, tail = int(LEAD_S * RATE), int(TAIL_S * RATE)
    total = lead + len(reply) + tail
    total += -total % BLOCK
    played = np.zeros(total, dtype=np.int16)
    played[lead : lead + len(reply)] = reply
    echo = ROOM.echo(played, RATE).astype(np.float64)
    echo *= 10 ** ((ECHO_DBFS - rms_dbfs(float_to_int16(echo[lead : lead + len(reply)] / 32768))) / 20)
    noise = np.random.default_rng(3).normal(0.0, NOISE, total)
    return (
        float_to_int16((echo + noise) / 32768),
        played,
        float_to_int16(noise / 32768),
        lead,
        lead + len(reply),
    )


def spotter_run(
    cancel_echo: bool, mic: Int16Array, played: Int16Array | None, span: tuple[int, int]
) -> float:
    """CPU seconds of one fresh spotter (built outside the timing: it loads its models) over `mic`,
    with `played` published while the robot plays (`span`, samples)."""
    spotter = StopSpotter(StopConfig(), cancel_echo=cancel_echo)
    cpu = 0.0
    for k in range(0, len(mic), BLOCK):
        stamp = T0 + k * NS // RATE
        began = time.process_time()
        if played is not None and span[0] <= k + BLOCK and k < span[1]:  # the player's blocks
            spotter.reference(played[k : k + BLOCK], RATE, 1, stamp)
        spotter.mic(mic[k : k + BLOCK], RATE, 1, stamp)
        cpu += time.process_time() - began
    return cpu


def echo_alone_run(mic: Int16Array, played: Int16Array, span: tuple[int, int]) -> float:
    """CPU seconds of the spotter's echo controller alone, cancelling while the robot plays."""
    echo = EchoController(EchoConfig(mode="aec", echo_guard_margin_db=ECHO_GUARD_MARGIN_DB))
    began = time.process_time()
    echo.set_assistant_speaking(True, T0)
    for k in range(0, min(len(mic), span[1] + RATE), BLOCK):  # the spotter cancels 1 s past the reply
        stamp = T0 + k * NS // RATE
        if span[0] <= k + BLOCK and k < span[1]:
            echo.add_reference(played[k : k + BLOCK], RATE, 1, stamp)
        echo.process(mic[k : k + BLOCK], stamp, stamp)
    return time.process_time() - began


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3, help="each scenario this many times, interleaved")
    args = parser.parse_args()
    started = time.monotonic()
    mic, played, quiet, first, last = scene()
    audio_s = len(mic) / RATE
    span = (first, last)
    scenarios: dict[str, Callable[[], float]] = {
        "silent": lambda: spotter_run(True, quiet, None, span),
        "speaking": lambda: spotter_run(True, mic, played, span),
        "no_cancel": lambda: spotter_run(False, mic, played, span),
        "echo_alone": lambda: echo_alone_run(mic, played, span),
        "reference": lambda: spotter_run(False, quiet, played, span),
    }
    percent: dict[str, list[float]] = {name: [] for name in scenarios}
    for _ in range(args.rounds):
        for name, run in scenarios.items():
            percent[name].append(100.0 * run() / audio_s)
    print(
        f"{audio_s:.1f} s of audio per run, the robot speaking {(last - first) / RATE:.1f} s of it; "
        f"{args.rounds} rounds in {time.monotonic() - started:.0f} s"
    )
    print(f"\n{'scenario':12} {'CPU % of one core (median)':>27} {'runs':>24} {'x silent':>9}")
    median = {name: statistics.median(values) for name, values in percent.items()}
    for name, values in percent.items():
        ratio = median[name] / median["silent"] if median["silent"] > 0 else float("nan")
        runs = " ".join(f"{v:.2f}" for v in values)
        print(f"{name:12} {median[name]:27.2f} {runs:>24} {ratio:9.1f}")
        emit("spotter_cpu", median[name], "% of one core", scenario=name, runs=values, ratio_to_silent=ratio)
    added = median["speaking"] - median["silent"]
    emit("spotter_speaking_added_cpu", added, "% of one core")
    # The clip has quiet before and after the reply; per second the robot actually speaks:
    per_spoken = median["speaking"] * len(mic) / (last - first)
    emit("spotter_cpu_per_spoken_second", per_spoken, "% of one core")
    print(
        f"\nthe spotter while the robot speaks (aec mode): {median['speaking']:.2f} % of one core, "
        f"+{added:.2f} over silent ({median['silent']:.2f}); its echo controller "
        f"{median['echo_alone']:.2f}, its decoding of the reference {median['reference']:.2f}; "
        f"without cancellation (the echo decoded as speech) {median['no_cancel']:.2f}; "
        f"per second the robot speaks: {per_spoken:.2f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
