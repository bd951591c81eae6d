"""Own pipeline latency of a voice turn (issue 9; goal <= 30 ms p95): the end of the user's speech
(the VAD's end-marker chunk published on prompt_voice) → the first reply audio at the player
(its playback_status reporting the new stream speaking; also the first `audio_played` block).

Real processes: ros_ai_bridge, simple_audio_player (real-time WAV sink), `byc agent` (OpenAI,
Gemini or GPT-Live provider, official SDK) → that provider's emulator answering at once (pace 0) on
a thread here (Gemini's over TLS). The bench node stands in for the VAD: 3 chunks of 100 ms every
100 ms, then the end-marker chunk. Includes the model's stand-in: commit (OpenAI) or activityEnd
(Gemini) → transcription → reply events on the emulator (a few ms). GPT-Live has no commit: the
model hears the user stop, so its figure includes the emulator's end-of-speech wait
(`end_silence_ms` of the silence the provider streams at real time); `own` subtracts that wait.

Baselines in the same run: one raw DDS publish→subscribe of the same chunk, one raw WebSocket round
trip of it. The turn crosses 3 DDS hops (bench→bridge, bridge→player, player→bench) and 2 WebSocket
round trips (bridge⇄agent, agent⇄emulator), so `floor` = 3 x DDS p50 + 2 x WebSocket p50.

    scripts/run.sh python bench/bench_agent_latency.py [--turns N] [--provider openai|gemini|gpt_live|all]
    unshare -n bash -c 'ip link set lo up; scripts/run.sh python bench/bench_agent_latency.py'
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _agent_bench import (  # noqa: E402
    CHUNK_MS,
    PROVIDERS,
    VAD_RATE,
    Stamped,
    agent_graph,
    dds_one_way_ms,
    percentile,
    summary,
    table,
    wait_until,
    websocket_round_trip_ms,
)

from by_your_command.emulators import gemini_script as gemini  # noqa: E402
from by_your_command.emulators import gpt_live_script as live  # noqa: E402
from by_your_command.emulators.openai_script import Say, Script  # noqa: E402

WARMUP_TURNS = 2
GOAL_P95_MS = 30.0
LIVE_END_SILENCE_MS = 300  # the GPT-Live emulator's end-of-speech wait (the real model's is its own)


def speech_like(seconds: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * VAD_RATE)) / VAD_RATE
    voice = 4000 * np.sin(2 * np.pi * 180 * t) * (1 + 0.5 * np.sin(2 * np.pi * 3 * t))
    return (voice + rng.normal(0, 300, len(t))).astype(np.int16)


def measure(provider: str, turns: int) -> dict[str, list[float]]:
    """The voice-turn figures of one provider's graph."""
    chunk = VAD_RATE * CHUNK_MS // 1000
    to_status: list[float] = []
    to_played: list[float] = []
    agent_first_audio: list[float] = []
    script: Script | gemini.Script | live.Script
    settings: dict[str, Any] = {}
    if provider == "gemini":
        script = gemini.Script(default_reply=gemini.Say("Okay."), pace=0.0, ms_per_char=40)
    elif provider == "gpt_live":
        script = live.Script(
            default_reply=live.Say("Okay."), pace=0.0, ms_per_char=40, end_silence_ms=LIVE_END_SILENCE_MS
        )
        settings["echo_mode"] = "aec"  # full duplex: a gated mic is refused
    else:
        script = Script(default_reply=Say("Okay."), pace=0.0, ms_per_char=40)
    with agent_graph(script, "latency", provider, **settings) as graph:
        bench = graph.bench
        known: set[str] = set()
        for turn in range(WARMUP_TURNS + turns):
            pcm = speech_like(0.4, turn)
            utterance = bench.new_utterance()
            bench.say_activity(True)
            pieces = [pcm[k : k + chunk] for k in range(0, len(pcm), chunk)]
            for sequence, piece in enumerate(pieces[:-1]):
                bench.voice.publish(bench.chunk(piece, utterance, sequence, False))
                time.sleep(CHUNK_MS / 1000)  # paced like the VAD
            last = bench.chunk(pieces[-1], utterance, len(pieces) - 1, True)
            played_before = len(bench.played)
            metrics_before = len(bench.metrics)
            ended = time.monotonic()
            bench.voice.publish(last)
            bench.say_activity(False)

            def first_status() -> Stamped | None:
                graph.check()
                return bench.new_stream(known)

            status = wait_until(first_status, 30, f"turn {turn}: the reply at the player")
            stream_id = status.msg.stream_id
            known.add(stream_id)

            def first_played(before: int = played_before, stream: str = stream_id) -> Stamped | None:
                return next((p for p in list(bench.played)[before:] if p.msg.stream_id == stream), None)

            def finished(stream: str = stream_id) -> bool:
                return any(s.msg.finished for s in bench.statuses_of(stream))

            def turn_record(before: int = metrics_before) -> dict[str, Any] | None:
                records = [json.loads(m.msg.data) for m in list(bench.metrics)[before:]]
                return next((r for r in records if r["record"] == "turn"), None)

            played = wait_until(first_played, 30, "the first played block")
            wait_until(finished, 30, "the reply played")
            record = wait_until(turn_record, 30, "the turn's metrics")
            if turn >= WARMUP_TURNS:
                to_status.append(1000 * (status.at - ended))
                to_played.append(1000 * (played.at - ended))
                if record["first_audio_ms"] is not None:
                    agent_first_audio.append(float(record["first_audio_ms"]))
        end_event = {"gemini": "activityEnd", "openai": "input_audio_buffer.commit"}.get(provider)
        ends = graph.emulator.received_types().count(end_event) if end_event else WARMUP_TURNS + turns
    assert ends == WARMUP_TURNS + turns, (
        f"{ends} turns ended at the {provider} emulator, not {WARMUP_TURNS + turns}"
    )
    return {
        "end_marker_to_speaking_status_ms": to_status,
        "end_marker_to_first_audio_played_ms": to_played,
        "agent_end_marker_to_first_audio_published_ms": agent_first_audio,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--turns", type=int, default=20)
    parser.add_argument("--provider", choices=(*PROVIDERS, "all"), default="all")
    args = parser.parse_args()
    providers = PROVIDERS if args.provider == "all" else (args.provider,)
    measured = {provider: measure(provider, args.turns) for provider in providers}

    dds = dds_one_way_ms(args.turns * 2, speech_like(CHUNK_MS / 1000, 99))
    ws = websocket_round_trip_ms(args.turns * 2, speech_like(CHUNK_MS / 1000, 99))
    floor = 3 * percentile(dds, 50) + 2 * percentile(ws, 50)
    for name, values in {
        "baseline_dds_publish_to_subscribe_ms": dds,
        "baseline_websocket_round_trip_ms": ws,
    }.items():
        print(json.dumps({"bench": "agent_latency", "figure": name, **summary(values)}))
    rows: list[tuple[str, list[float], str]] = []
    for provider, figures in measured.items():
        to_status = figures["end_marker_to_speaking_status_ms"]
        if provider == "gpt_live":  # the model's own end-of-speech wait is not ours: compare the rest
            figures["end_marker_to_speaking_status_ms_with_model_wait"] = to_status
            to_status = [value - LIVE_END_SILENCE_MS for value in to_status]
            figures["end_marker_to_speaking_status_ms"] = to_status
        for name, values in figures.items():
            print(
                json.dumps(
                    {"bench": "agent_latency", "provider": provider, "figure": name, **summary(values)}
                )
            )
        p95 = percentile(to_status, 95)
        print(
            json.dumps(
                {
                    "bench": "agent_latency",
                    "provider": provider,
                    "figure": "pipeline_vs_transport_floor",
                    "p50_ratio_vs_floor": round(percentile(to_status, 50) / floor, 2),
                    "floor_ms": round(floor, 2),
                    "goal_p95_ms": GOAL_P95_MS,
                    "meets_goal": p95 <= GOAL_P95_MS,
                }
            )
        )
        rows += [
            (f"{provider}: end marker -> speaking status", to_status, f"goal p95 <= {GOAL_P95_MS:g} ms"),
            (
                f"{provider}: end marker -> first audio_played",
                figures["end_marker_to_first_audio_played_ms"],
                "",
            ),
            (
                f"{provider}:   in the agent: -> audio published",
                figures["agent_end_marker_to_first_audio_published_ms"],
                "agent's TurnMetrics",
            ),
            (
                f"{provider}: pipeline / transport floor",
                [percentile(to_status, 50) / floor],
                "ratio of p50s (not ms)",
            ),
        ]
    rows += [
        ("baseline: DDS publish -> subscribe", dds, "one hop"),
        ("baseline: WebSocket round trip", ws, "one round trip"),
        ("transport floor (3 DDS + 2 WS)", [floor], "3 x DDS p50 + 2 x WS p50"),
    ]
    table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
