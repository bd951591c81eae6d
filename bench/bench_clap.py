"""Double-clap wake: detection rate on generated double claps (4 timbres, rooms RT60 0.2-0.9 s,
peak 0.02-0.6, 4 room noises, gaps 200-900 ms), false wakes per hour of speech (espeak-ng sentences
full of plosives, several voices, dry / in a room / in a room with noise, plus the committed speech
corpus), and CPU per second of audio; the detector before issue 8 (bench/_old_clap.py) is the
baseline, run on the same audio in the same run.

The figures are for the HELD_OUT set (seeds, voices and sentences the detector was not tuned on);
`--set tuning` measures the tuning set instead.

    scripts/run.sh python bench/bench_clap.py [--set held_out|tuning] [--claps N] [--speech-minutes M]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Protocol

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[0] / "by_your_command" / "test"))
sys.path.insert(0, str(HERE))

import _old_clap  # noqa: E402
from vad.corpus import sessions  # type: ignore[import-not-found]  # noqa: E402
from wake.clap_corpus import (  # type: ignore[import-not-found]  # noqa: E402
    HELD_OUT,
    RATE,
    TUNING,
    ClapScene,
    CorpusSet,
    double_clap_scenes,
    speech_stream,
)

from by_your_command.audio import clap  # noqa: E402
from by_your_command.audio.pcm import Int16Array  # noqa: E402

BLOCK = 512  # what audio_capture publishes
TOLERANCE = RATE // 20  # a detected clap within 50 ms of a placed one is that clap


class Detector(Protocol):
    def process(self, pcm: Int16Array) -> Sequence[object]: ...


DETECTORS: dict[str, tuple[Callable[[], Detector], type, type]] = {
    "old": (lambda: _old_clap.ClapDetector(_old_clap.ClapConfig()), _old_clap.DoubleClap, _old_clap.Clap),
    "new": (lambda: clap.ClapDetector(clap.ClapConfig()), clap.DoubleClap, clap.Clap),
}


def run(name: str, pcm: Int16Array) -> tuple[list[object], float]:
    """Events and CPU seconds for one pass over `pcm` in BLOCK-sample blocks."""
    make, _, _ = DETECTORS[name]
    detector = make()
    events: list[object] = []
    began = time.process_time()
    for offset in range(0, len(pcm), BLOCK):
        events += detector.process(pcm[offset : offset + BLOCK])
    return events, time.process_time() - began


def clap_times(event: object) -> tuple[float, float]:
    first, second = getattr(event, "first"), getattr(event, "second")  # noqa: B009
    return float(first.time_s), float(second.time_s)


def detected(name: str, scene: ClapScene, events: list[object]) -> bool:
    doubles = [e for e in events if isinstance(e, DETECTORS[name][1])]
    placed = [s / RATE for s in scene.clap_samples]
    return len(doubles) == 1 and all(
        abs(found - at) <= TOLERANCE / RATE for found, at in zip(clap_times(doubles[0]), placed, strict=True)
    )


def emit(
    figure: dict[str, object], rows: list[tuple[str, str, str]], label: str, value: str, note: str
) -> None:
    print(json.dumps({"bench": "clap", **figure}), flush=True)
    rows.append((label, value, note))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--set", choices=("held_out", "tuning"), default="held_out")
    parser.add_argument("--claps", type=int, default=100, help="double-clap scenes")
    parser.add_argument("--speech-minutes", type=float, default=5.0, help="per speech condition")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})  # one core
    corpus: CorpusSet = HELD_OUT if args.set == "held_out" else TUNING
    rows: list[tuple[str, str, str]] = []

    scenes = double_clap_scenes(corpus.clap_seed, args.claps)
    clap_seconds = sum(s.seconds for s in scenes)
    cpu: dict[str, list[float]] = {"old": [], "new": []}
    for name in DETECTORS:
        hits = 0
        by_timbre: dict[str, list[bool]] = {}
        far_hits = []
        for scene in scenes:
            events, spent = run(name, scene.pcm)
            cpu[name].append(spent / scene.seconds)
            ok = detected(name, scene, events)
            hits += ok
            by_timbre.setdefault(scene.description.split()[0], []).append(ok)
            if "peak=0.0" in scene.description:  # peak below 0.1: the far claps
                far_hits.append(ok)
        rate = hits / len(scenes)
        emit(
            {
                "figure": "double_claps_detected",
                "detector": name,
                "set": corpus.name,
                "value": round(rate, 3),
                "of": len(scenes),
                "far_detected": round(sum(far_hits) / max(len(far_hits), 1), 3),
                "by_timbre": {t: round(sum(v) / len(v), 2) for t, v in by_timbre.items()},
            },
            rows,
            f"double claps detected, {name}",
            f"{100 * rate:.0f} %",
            f"{hits}/{len(scenes)}; far (peak < 0.1): {sum(far_hits)}/{len(far_hits)}; "
            + ", ".join(f"{t} {sum(v)}/{len(v)}" for t, v in by_timbre.items()),
        )

    conditions: list[tuple[str, Int16Array]] = []
    for label, noisy, reverberant in (
        ("dry", False, False),
        ("room", False, True),
        ("room+noise", True, True),
    ):
        pcm, _ = speech_stream(corpus, 60.0 * args.speech_minutes, noisy, reverberant)
        conditions.append((f"espeak {label}", pcm))
    conditions.append(("committed corpus", np.concatenate([s.audio() for s in sessions()])))
    for name in DETECTORS:
        total_s = 0.0
        total_wakes = 0
        total_claps = 0
        for label, pcm in conditions:
            events, spent = run(name, pcm)
            seconds = len(pcm) / RATE
            cpu[name].append(spent / seconds)
            wakes = sum(isinstance(e, DETECTORS[name][1]) for e in events)
            singles = sum(isinstance(e, DETECTORS[name][2]) for e in events)
            total_s += seconds
            total_wakes += wakes
            total_claps += singles
            emit(
                {
                    "figure": "false_wakes_per_hour",
                    "detector": name,
                    "set": corpus.name,
                    "speech": label,
                    "value": round(3600 * wakes / seconds, 1),
                    "false_wakes": wakes,
                    "false_claps": singles,
                    "speech_s": round(seconds, 1),
                },
                rows,
                f"false wakes/h, {name}, {label}",
                f"{3600 * wakes / seconds:.1f}",
                f"{wakes} wakes, {singles} single claps in {seconds / 60:.1f} min",
            )
        emit(
            {
                "figure": "false_wakes_per_hour",
                "detector": name,
                "set": corpus.name,
                "speech": "all",
                "value": round(3600 * total_wakes / total_s, 1),
                "false_wakes": total_wakes,
                "false_claps": total_claps,
                "speech_s": round(total_s, 1),
            },
            rows,
            f"false wakes/h, {name}, all speech",
            f"{3600 * total_wakes / total_s:.1f}",
            f"{total_wakes} wakes, {total_claps} single claps in {total_s / 60:.1f} min",
        )

    medians = {name: statistics.median(values) for name, values in cpu.items()}
    for name, value in medians.items():
        emit(
            {
                "figure": "cpu_per_audio_second_ms",
                "detector": name,
                "value": round(1000 * value, 2),
                "ratio_vs_old": round(value / medians["old"], 2),
                "unit": "ms",
            },
            rows,
            f"CPU per second of audio, {name}",
            f"{1000 * value:.2f} ms",
            f"median of {len(cpu[name])} clips; {value / medians['old']:.1f}x old; "
            f"{100 * value:.2f} % of one core",
        )
    width = max(len(r[0]) for r in rows)
    print(f"\nset: {corpus.name}, clap audio {clap_seconds / 60:.1f} min")
    for label, shown, note in rows:
        print(f"{label:<{width}}  {shown:>9}  {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
