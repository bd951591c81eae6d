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
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "by_your_command" / "test"))

from audio_io.synthetic_room import (  # type: ignore[import-not-found]  # noqa: E402
    Conversation,
    Room,
    at_level,
    conversation,
    energy_db,
    recorded_speech,
    speech_like,
)

from by_your_command.audio import echo_memory  # noqa: E402
from by_your_command.audio.echo import EchoConfig, EchoController  # noqa: E402
from by_your_command.audio.pcm import (  # noqa: E402
    Int16Array,
    StreamResampler,
    float_to_int16,
    resample,
    rms_dbfs,
)
from by_your_command.vad.config import VadConfig  # noqa: E402
from by_your_command.vad.detector import VoiceDetector  # noqa: E402
from by_your_command.vad.model import SileroModel  # noqa: E402
from by_your_command.vad.segmenter import VoiceActivity  # noqa: E402

RATE = 16000
BLOCK = 512
SECONDS = 10.0
CONVERGED_FROM_S = 3.0
LEARN_S = 30.0  # double talk, remembered path: the robot's earlier speech in the room
T0 = 1_700_000_000 * 1_000_000_000


def run(
    mode: str, far: Int16Array, mic: Int16Array, engine: str = "webrtc", residual: bool = False
) -> tuple[Int16Array, float, int]:
    """(output, seconds of CPU spent in the controller, 10 ms frames processed); `residual`: the
    linear engine's residual suppressor on."""
    echo = EchoController(EchoConfig(mode=mode, echo_guard=residual, aec_engine=engine))
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
    # AEC3 alone (its guard mutes frames, which is not cancelling); the linear filter as it runs
    # by default, with its residual suppressor (alone it converges slower than AEC3 on speech).
    for engine in ("webrtc", "linear"):
        for signal_name, far in signals.items():
            for room_name, room in rooms.items():
                mic = room.echo(far, RATE)
                out, spent, frames = run("aec", far, mic, engine, residual=engine == "linear")
                lo = int(CONVERGED_FROM_S * RATE)
                reduction = energy_db(mic[lo : len(out)]) - energy_db(out[lo:])
                per_second = [
                    energy_db(mic[s : s + RATE]) - energy_db(out[s : s + RATE])
                    for s in range(lo, len(out) - RATE + 1, RATE)
                ]
                figure(
                    figure="echo_reduction_db",
                    engine=engine,
                    signal=signal_name,
                    room=room_name,
                    value=round(reduction, 1),
                    median_per_second_db=round(statistics.median(per_second), 1),
                    unit="dB",
                )
                rows.append(
                    (
                        f"echo reduction {engine} {signal_name}/{room_name}",
                        f"{reduction:.1f} dB",
                        f"median/s {statistics.median(per_second):.1f} dB"
                        + (" (with residual suppression)" if engine == "linear" else " (no guard)"),
                    )
                )
    far = signals["speech"]
    mic = Room().echo(far, RATE)
    costs = {}
    for mode, engine in (("external", ""), ("gate", ""), ("aec", "webrtc"), ("aec", "linear")):
        samples = []
        for _ in range(3):
            _, spent, frames = run(mode, far, mic, engine or "webrtc", residual=engine == "linear")
            samples.append(spent / frames * 1e6)
        costs[f"{mode} {engine}".strip()] = statistics.median(samples)
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
    rows += bench_double_talk()
    print_rows(rows)
    return 0


def print_rows(rows: list[tuple[str, str, str]]) -> None:
    width = max(len(r[0]) for r in rows)
    print()
    for name, value, note in rows:
        print(f"{name:<{width}}  {value:>10}  {note}")


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


# Echo control compared everywhere below: AEC3 alone, AEC3 + the whole-frame guard (the old
# default), and the linear filter + per-band residual suppression (the new default).
CONFIGS = {
    "webrtc_guard_off": EchoConfig(mode="aec", aec_engine="webrtc", echo_guard=False),
    "webrtc_guard_on": EchoConfig(mode="aec", aec_engine="webrtc", echo_guard=True),
    "linear_new": EchoConfig(mode="aec", aec_engine="linear", echo_guard=True),
}
# Double talk only: linear_new started from the echo path it remembered of the room (a robot that
# spoke there before: LEARN_S of other speech), not new as in every other row.
REMEMBERED = "linear_remembered"


@dataclass
class Listened:
    """What the echo control let through (laid on the mic's sample clock by the output stamps)
    and when the real Silero VAD started utterances in it (s)."""

    output: npt.NDArray[np.float64]
    starts: list[float]


def listen(
    talk: Conversation,
    config: EchoConfig,
    model: SileroModel | None,
    start_from: Path | None = None,
    keep_to: Path | None = None,
) -> Listened:
    """`start_from`: a remembered echo path to start from; `keep_to`: remember the one learned."""
    echo = EchoController(config)
    if start_from is not None:
        restored = echo_memory.restore(echo, start_from)
        assert restored.ok and "starting from" in restored.message, restored.message
    detector = None
    if model is not None:
        model.reset()
        detector = VoiceDetector(VadConfig(), model)
    output = np.zeros(len(talk.mic))
    starts = []
    echo.set_assistant_speaking(True, T0)
    played, mic = talk.played, talk.mic
    for k in range(0, len(mic) // BLOCK * BLOCK, BLOCK):
        start = T0 + k * 1_000_000_000 // RATE
        echo.add_reference(played[k : k + BLOCK], RATE, 1, start)
        for block in echo.process(mic[k : k + BLOCK], start, start) + echo.drain():
            at = round((block.start_ns - T0) * RATE / 1e9)
            n = max(0, min(len(block.pcm), len(output) - at))
            output[at : at + n] = block.pcm[:n]
            if detector is None:
                continue
            for event in detector.process(block.pcm, RATE, 1, block.start_ns):
                if isinstance(event, VoiceActivity) and event.active:
                    starts.append((event.time_ns - T0) / 1e9)
    if keep_to is not None:
        kept = echo_memory.keep(echo, keep_to)
        assert kept is not None and kept.ok, kept
    return Listened(output, starts)


def utterance_starts(talk: Conversation, config: EchoConfig, model: SileroModel) -> list[float]:
    return listen(talk, config, model).starts


def bench_echo_guard() -> list[tuple[str, str, str]]:
    """Real Silero on the echo control's output of a robot talking ~16 s: user sentences over it
    detected (double talk) and utterances started by nothing but the robot's echo, per config."""
    model = SileroModel()
    rooms = {
        "robot_body": Room(delay_ms=70, reverb_ms=120, reverb_gain=0.08),
        "reverberant": Room(delay_ms=120),
    }
    rows = []
    for room_name, room in rooms.items():
        for name, config in CONFIGS.items():
            hits = users = false = 0
            seconds = 0.0
            for echo_dbfs in (-26.0, -20.0, -14.0):
                for user_dbfs in (None, -26.0, -32.0):
                    user_at = (3.0, 6.5, 10.0) if user_dbfs is not None else ()
                    talk = conversation(
                        RATE, room, echo_dbfs=echo_dbfs, user_dbfs=user_dbfs or -26.0, user_at_s=user_at
                    )
                    starts = utterance_starts(talk, config, model)
                    spans = talk.user_spans
                    hits += sum(any(b - 0.1 <= s <= e for s in starts) for b, e in spans)
                    users += len(spans)
                    false += sum(not any(b - 0.1 <= s <= e + 0.3 for b, e in spans) for s in starts)
                    seconds += len(talk.mic) / RATE
            per_minute = false / seconds * 60
            figure(
                figure="echo_guard",
                room=room_name,
                config=name,
                double_talk_detected=hits,
                double_talk_total=users,
                false_starts=false,
                false_starts_per_min=round(per_minute, 2),
                robot_speech_s=round(seconds, 1),
            )
            rows.append(
                (
                    f"echo control {name} {room_name}",
                    f"{hits}/{users} DT",
                    f"{false} false starts in {seconds:.0f} s ({per_minute:.1f}/min)",
                )
            )
    return rows


@dataclass(frozen=True)
class Scene:
    """One room and one user: the robot's echo at `echo_dbfs`, the user at `user_dbfs` (the
    level a user a metre away has with the robot silent), speaking at `user_at_s`."""

    room_name: str
    room: Room
    echo_dbfs: float
    voice: str | None  # espeak-ng voice; None: the corpus recording
    user_dbfs: float = -26.0
    user_at_s: tuple[float, ...] = (3.0, 6.5, 10.0)
    user_room: Room | None = None


def scenes(held_out: bool) -> list[Scene]:
    """Tuned-on scenes, or the held-out ones (other rooms, voices, levels and times), only
    evaluated. Echo as loud as the user (-26 dBFS) or louder (-20)."""
    if not held_out:
        rooms = {
            "robot_body": Room(delay_ms=70, reverb_ms=120, reverb_gain=0.08),
            "reverberant": Room(delay_ms=120),
            "long_tail": Room(delay_ms=150, reverb_ms=250, reverb_gain=0.4),
        }
        voices: tuple[str | None, ...] = (None, "en-us+f3")
        return [
            Scene(name, room, echo, voices[k % 2])
            for k, (name, room) in enumerate(rooms.items())
            for echo in (-26.0, -20.0)
        ]
    rooms = {
        "small_office": Room(delay_ms=40, gain=0.8, reverb_ms=90, reverb_gain=0.1),
        "living_room": Room(delay_ms=100, gain=0.5, reverb_ms=200, reverb_gain=0.2, noise_dbfs=-55.0),
        "hall": Room(delay_ms=180, gain=0.4, reverb_ms=300, reverb_gain=0.3),
    }
    voices = ("en-gb-scotland+m3", "en-us+f4", "en+m7")
    return [
        Scene(
            name,
            room,
            echo,
            voices[(k + j) % 3],
            user_dbfs=-26.0 - 3.0 * j,
            user_at_s=(2.5, 7.0, 11.0),
            user_room=Room(delay_ms=3, gain=1.0, reverb_ms=60, reverb_gain=0.1, noise_dbfs=-90.0),
        )
        for k, (name, room) in enumerate(rooms.items())
        for j, echo in enumerate((-26.0, -20.0))
    ]


def remember_room(scene: Scene, config: EchoConfig, file: Path) -> None:
    """The echo path a robot keeps after LEARN_S of other speech in the scene's room (the same
    room response, the same echo level): what it starts the scene from when the path is remembered."""
    played = at_level(recorded_speech(LEARN_S, RATE), -18.0)
    echo = scene.room.echo(played, RATE).astype(np.float64)
    echo *= 10 ** ((scene.echo_dbfs - rms_dbfs(float_to_int16(echo / 32768.0))) / 20)
    earlier = Conversation(played, float_to_int16(echo / 32768.0), [], RATE)
    listen(earlier, config, None, keep_to=file)


def talk_of(scene: Scene, with_user: bool, echo: bool = True) -> Conversation:
    return conversation(
        RATE,
        scene.room,
        echo_dbfs=scene.echo_dbfs if echo else -200.0,
        user_dbfs=scene.user_dbfs,
        user_at_s=scene.user_at_s if with_user else (),
        user_voice=scene.voice,
        user_room=scene.user_room,
    )


def pearson(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float(np.dot(a, b) / (np.sqrt(np.dot(a, a) * np.dot(b, b)) + 1e-12))


def first_start(starts: list[float], begin: float, end: float) -> float | None:
    """Delay (ms) from `begin` to the first utterance start in [begin - 0.1, end], if any."""
    hits = [s for s in starts if begin - 0.1 <= s <= end]
    return (hits[0] - begin) * 1000 if hits else None


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def bench_double_talk(held_out_too: bool = True) -> list[tuple[str, str, str]]:
    """The user at the level they have with the robot silent, talking over the robot's voice:
    - detected: a Silero onset on the output between 0.1 s before and the end of each sentence
      (during the robot's speech); onset delay from the sentence's first sound, p50/p95, against
      the same sentences with nothing playing (same config, same run);
    - near-end correlation: Pearson correlation, sample by sample, of the output over each
      sentence's span with what the same config outputs for the user alone with nothing played
      (so AEC3's fixed high-pass and framing count as undistorted; only what the robot's
      playing does to the user counts: suppression, distortion and echo left in);
    - single talk (robot only): echo attenuation (ERLE, mic vs output energy from 3 s on, the
      robot speaking) and Silero utterance starts per minute of robot speech."""
    model = SileroModel()
    rows = []
    workspace = tempfile.TemporaryDirectory(prefix="bench_aec_")  # the remembered echo paths
    for held_out in (False, True) if held_out_too else (False,):
        label = "held-out" if held_out else "tuned"
        chosen = scenes(held_out)
        talks = [(talk_of(s, True), talk_of(s, True, echo=False), talk_of(s, False)) for s in chosen]
        quiet_runs: dict[tuple[str, int], Listened] = {}  # nothing played: the guard has no say
        memory = Path(workspace.name) / label
        memory.mkdir()
        for index, scene in enumerate(chosen):
            remember_room(scene, CONFIGS["linear_new"], memory / f"{index}.npz")
        for name, config in {**CONFIGS, REMEMBERED: CONFIGS["linear_new"]}.items():
            delays: list[float] = []
            quiet_delays: list[float] = []
            correlations: list[float] = []
            detected = total = false_starts = 0
            erles: list[float] = []
            robot_s = 0.0
            for index, (talk, alone, single) in enumerate(talks):
                scene_delays: list[float | None] = []
                scene_correlations: list[float] = []
                remembered = memory / f"{index}.npz" if name == REMEMBERED else None
                heard = listen(talk, config, model, start_from=remembered)
                key = (config.aec_engine, index)
                if key not in quiet_runs:
                    quiet_runs[key] = listen(
                        replace(alone, played=np.zeros_like(alone.played)), config, model
                    )
                quiet = quiet_runs[key]
                robot_end = len(talk.played) / RATE - 0.5  # the reply's trailing silence
                for begin, end in talk.user_spans:
                    if begin >= robot_end:
                        continue
                    total += 1
                    delay = first_start(heard.starts, begin, end)
                    scene_delays.append(delay)
                    detected += delay is not None
                    delays += [delay] if delay is not None else []
                    baseline = first_start(quiet.starts, begin, end)
                    quiet_delays += [baseline] if baseline is not None else []
                    span = slice(int(begin * RATE), int(min(end, robot_end) * RATE))
                    scene_correlations.append(pearson(heard.output[span], quiet.output[span]))
                correlations += scene_correlations
                robot = listen(single, config, model, start_from=remembered)
                lo, hi = int(CONVERGED_FROM_S * RATE), int(robot_end * RATE)
                mic = single.mic[lo:hi]
                erles.append(energy_db(mic) - energy_db(np.rint(robot.output[lo:hi]).astype(np.int16)))
                false_starts += len(robot.starts)
                scene = chosen[index]
                figure(  # per room and echo level: where a set's figures are lost
                    figure="double_talk_scene",
                    set=label,
                    config=name,
                    room=scene.room_name,
                    echo_dbfs=scene.echo_dbfs,
                    onset_ms=[None if d is None else round(d) for d in scene_delays],
                    correlation=[round(c, 3) for c in scene_correlations],
                    single_talk_erle_db=round(erles[-1], 1),
                    false_starts=len(robot.starts),
                )
                robot_s += robot_end - 0.5
            per_minute = false_starts / robot_s * 60
            figure(
                figure="double_talk",
                set=label,
                config=name,
                detected=detected,
                total=total,
                onset_ms_p50=round(percentile(delays, 50)),
                onset_ms_p95=round(percentile(delays, 95)),
                quiet_onset_ms_p50=round(percentile(quiet_delays, 50)),
                quiet_onset_ms_p95=round(percentile(quiet_delays, 95)),
                correlation_median=round(statistics.median(correlations), 3),
                correlation_min=round(min(correlations), 3),
                correlation_at_least_0_8=sum(c >= 0.8 for c in correlations),
                single_talk_erle_db_min=round(min(erles), 1),
                single_talk_erle_db_median=round(statistics.median(erles), 1),
                false_starts_per_min=round(per_minute, 2),
            )
            rows.append(
                (
                    f"double talk {label} {name}",
                    f"{detected}/{total} DT",
                    f"onset p50/p95 {percentile(delays, 50):.0f}/{percentile(delays, 95):.0f} ms "
                    f"(nothing playing {percentile(quiet_delays, 50):.0f}/"
                    f"{percentile(quiet_delays, 95):.0f}), "
                    f"corr median {statistics.median(correlations):.2f} min {min(correlations):.2f} "
                    f"({sum(c >= 0.8 for c in correlations)}/{len(correlations)} >= 0.8), "
                    f"ERLE min {min(erles):.1f} median {statistics.median(erles):.1f} dB, "
                    f"{per_minute:.1f} false starts/min",
                )
            )
    workspace.cleanup()
    return rows


if __name__ == "__main__":
    if sys.argv[1:] == ["--double-talk"]:  # just the double-talk part (a minute)
        print_rows(bench_double_talk())
        sys.exit(0)
    sys.exit(main())
