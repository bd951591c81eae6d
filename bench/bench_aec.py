"""Echo control, all measured in this run: AEC3 echo reduction (dB) on synthetic rooms; CPU per
10 ms frame of aec vs gate vs pass-through; the stream resampler's added latency and cost vs
stateless per-block resampling; mic-to-output latency with nothing playing vs the old always-wait;
and the echo guard: double talk detected vs false utterance starts of the real Silero VAD on the
AEC output, guard on vs off.

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
    conversation,
    energy_db,
    recorded_speech,
    speech_like,
)

from by_your_command.audio.echo import EchoConfig, EchoController  # noqa: E402
from by_your_command.audio.pcm import Int16Array, StreamResampler, float_to_int16, resample  # noqa: E402
from by_your_command.vad.config import VadConfig  # noqa: E402
from by_your_command.vad.detector import VoiceDetector  # noqa: E402
from by_your_command.vad.model import SileroModel  # noqa: E402
from by_your_command.vad.segmenter import VoiceActivity  # noqa: E402

RATE = 16000
BLOCK = 512
SECONDS = 10.0
CONVERGED_FROM_S = 3.0
T0 = 1_700_000_000 * 1_000_000_000


def run(mode: str, far: Int16Array, mic: Int16Array) -> tuple[Int16Array, float, int]:
    """(output, seconds of CPU spent in the controller, 10 ms frames processed)."""
    echo = EchoController(EchoConfig(mode=mode, echo_guard=False))
    echo.set_assistant_speaking(True, T0)
    outs = []
    spent = 0.0
    for k in range(0, len(mic) // BLOCK * BLOCK, BLOCK):
        start = T0 + k * 1_000_000_000 // RATE
        began = time.process_time()
        echo.add_reference(far[k : k + BLOCK], RATE, 1, start)
        blocks = echo.process(mic[k : k + BLOCK], start, start)
        spent += time.process_time() - began
        outs += [b.pcm for b in blocks]
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
    rows += bench_resampler()
    rows += bench_quiet_latency()
    rows += bench_echo_guard()
    width = max(len(r[0]) for r in rows)
    print()
    for name, value, note in rows:
        print(f"{name:<{width}}  {value:>10}  {note}")
    return 0


def figure(**fields: object) -> None:
    print(json.dumps({"bench": "aec", **fields}))


def bench_resampler() -> list[tuple[str, str, str]]:
    """Latency the stateful resampler adds (held back while streaming) and its CPU per 32 ms
    block against stateless per-block resampling (the clicking baseline it replaced)."""
    rows = []
    for src in (48000, 44100, 24000):
        block = src * 32 // 1000
        signal = speech_like(4.0, src, seed=3)
        blocks = [signal[k : k + block] for k in range(0, len(signal) - block, block)]
        stream, stateless, held = [], [], []
        for _ in range(3):
            resampler = StreamResampler(src, RATE)
            began = time.process_time()
            for b in blocks:
                resampler.push(b)
                held.append(resampler.held_back_s * 1000)
            stream.append((time.process_time() - began) / len(blocks) * 1e6)
            began = time.process_time()
            for b in blocks:
                resample(b, src, RATE)
            stateless.append((time.process_time() - began) / len(blocks) * 1e6)
        cost, base = statistics.median(stream), statistics.median(stateless)
        latency = statistics.median(held)
        figure(figure="resampler_latency_ms", from_rate=src, to_rate=RATE, value=round(latency, 3), unit="ms")
        figure(
            figure="resampler_cpu_per_block_us",
            from_rate=src,
            value=round(cost, 1),
            ratio_vs_stateless=round(cost / base, 2),
            unit="us",
        )
        rows.append((f"resample {src}->{RATE} latency", f"{latency:.2f} ms", "held back while streaming"))
        rows.append((f"resample {src}->{RATE} CPU/32 ms", f"{cost:.0f} us", f"{cost / base:.2f}x stateless"))
    return rows


def held_back_ms(speaking: bool) -> float:
    """Median mic-to-output latency (ms of captured audio not yet out after each block) with
    nothing playing; `speaking` True without reference is how every block was treated before."""
    echo = EchoController(EchoConfig(mode="aec"))
    echo.set_assistant_speaking(speaking, T0)
    fed = out = 0
    held = []
    for k in range(200):
        start = T0 + k * BLOCK * 1_000_000_000 // RATE
        out += sum(len(b.pcm) for b in echo.process(np.zeros(BLOCK, dtype=np.int16), start, start))
        fed += BLOCK
        held.append((fed - out) * 1000 / RATE)
    return statistics.median(held[10:])


def bench_quiet_latency() -> list[tuple[str, str, str]]:
    quiet, waiting = held_back_ms(False), held_back_ms(True)
    delay = EchoController(EchoConfig(mode="aec")).aec_delay_samples * 1000 / RATE
    figure(figure="aec_own_delay_ms", value=round(delay, 2), unit="ms")
    figure(
        figure="mic_held_back_ms_nothing_playing",
        value=round(quiet, 1),
        baseline_always_wait=round(waiting, 1),
        ratio=round(quiet / waiting, 2),
        unit="ms",
    )
    return [
        ("AEC3's own delay (stamps corrected)", f"{delay:.1f} ms", "measured at start-up"),
        ("mic held back, nothing playing", f"{quiet:.1f} ms", f"always-wait baseline {waiting:.1f} ms"),
    ]


def utterance_starts(talk: object, guard: bool, model: SileroModel) -> list[float]:
    echo = EchoController(EchoConfig(mode="aec", echo_guard=guard))
    model.reset()
    detector = VoiceDetector(VadConfig(), model)
    starts = []
    echo.set_assistant_speaking(True, T0)
    played, mic = talk.played, talk.mic  # type: ignore[attr-defined]
    for k in range(0, len(mic) // BLOCK * BLOCK, BLOCK):
        start = T0 + k * 1_000_000_000 // RATE
        echo.add_reference(played[k : k + BLOCK], RATE, 1, start)
        for block in echo.process(mic[k : k + BLOCK], start, start):
            for event in detector.process(block.pcm, RATE, 1, block.start_ns):
                if isinstance(event, VoiceActivity) and event.active:
                    starts.append((event.time_ns - T0) / 1e9)
    return starts


def bench_echo_guard() -> list[tuple[str, str, str]]:
    """Real Silero on the AEC output of a robot talking ~16 s: user sentences over it detected
    (double talk) and utterances started by nothing but the robot's echo, guard on vs off."""
    model = SileroModel()
    rooms = {
        "robot_body": Room(delay_ms=70, reverb_ms=120, reverb_gain=0.08),
        "reverberant": Room(delay_ms=120),
    }
    rows = []
    for room_name, room in rooms.items():
        for guard in (False, True):
            hits = users = false = 0
            seconds = 0.0
            for echo_dbfs in (-26.0, -20.0, -14.0):
                for user_dbfs in (None, -26.0, -32.0):
                    user_at = (3.0, 6.5, 10.0) if user_dbfs is not None else ()
                    talk = conversation(
                        RATE, room, echo_dbfs=echo_dbfs, user_dbfs=user_dbfs or -26.0, user_at_s=user_at
                    )
                    starts = utterance_starts(talk, guard, model)
                    spans = talk.user_spans
                    hits += sum(any(b - 0.1 <= s <= e for s in starts) for b, e in spans)
                    users += len(spans)
                    false += sum(not any(b - 0.1 <= s <= e + 0.3 for b, e in spans) for s in starts)
                    seconds += len(talk.mic) / RATE
            per_minute = false / seconds * 60
            figure(
                figure="echo_guard",
                room=room_name,
                guard=guard,
                double_talk_detected=hits,
                double_talk_total=users,
                false_starts=false,
                false_starts_per_min=round(per_minute, 2),
                robot_speech_s=round(seconds, 1),
            )
            rows.append(
                (
                    f"echo guard {'on ' if guard else 'off'} {room_name}",
                    f"{hits}/{users} DT",
                    f"{false} false starts in {seconds:.0f} s ({per_minute:.1f}/min)",
                )
            )
    return rows


if __name__ == "__main__":
    sys.exit(main())
