"""Barge-in latency (issue 9; goal <= 150 ms p95): the user's speech onset in the microphone stream
(voice_activity True and the first chunk of the interrupting utterance published) → the player
silent for the reply it was playing (its playback_status for that stream: interrupted, not
speaking).

Real processes: ros_ai_bridge, simple_audio_player (real-time WAV sink, 20 ms blocks), `byc agent`
(echo_mode external: full duplex) → the OpenAI or Gemini emulator on a thread here. Each trial: a
typed question, a 6 s story playing; after 300 ms of it the bench "speaks" 500 ms (chunks every
100 ms like the VAD), which confirms the barge-in; the agent cancels and truncates the story
(OpenAI) or opens an activity that the server answers with `interrupted` (Gemini: the story is
generated in real time, so it is still being generated when cut), sends the utterance and the
short answer plays; then the next trial.

The path crosses 3 DDS hops (bench→bridge, bridge→player, player→bench) and one WebSocket round
trip (bridge→agent→bridge), plus at most one player block: the same-run baselines (a raw DDS
publish→subscribe, a raw WebSocket round trip) give that floor.

    scripts/run.sh python bench/bench_barge_in.py [--trials N] [--provider openai|gemini|all]
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
from by_your_command.emulators.openai_script import Say, Script, Turn  # noqa: E402

GOAL_P95_MS = 150.0
PLAYED_BEFORE_MS = 300
STORY = "Once upon a time a robot told a very long story about everything it saw." * 2  # ~6 s
BLOCK_MS = 20  # the player's default block


def speech_like(seconds: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * VAD_RATE)) / VAD_RATE
    return (4000 * np.sin(2 * np.pi * 200 * t) + rng.normal(0, 300, len(t))).astype(np.int16)


def script_for(provider: str, trials: int) -> Script | gemini.Script:
    if provider == "gemini":
        replies = (gemini.Turn(gemini.Say(STORY)), gemini.Turn(gemini.Say("Yes?")))
        return gemini.Script(turns=replies * (trials + 1), pace=1.0, ms_per_char=40)
    return Script(turns=(Turn(Say(STORY)), Turn(Say("Yes?"))) * (trials + 1), pace=0.0, ms_per_char=40)


def measure(provider: str, trials: int) -> list[float]:
    """Speech onset → player silent, per trial after the first, with one provider's graph."""
    chunk = VAD_RATE * CHUNK_MS // 1000
    latencies: list[float] = []
    settings: dict[str, Any] = {"echo_mode": "external", "min_barge_in_ms": 400, "barge_in_window_s": 2.0}
    with agent_graph(script_for(provider, trials), "barge_in", provider, **settings) as graph:
        bench = graph.bench
        known: set[str] = set()
        for trial in range(trials + 1):  # the first one warms up
            bench.type_text("tell me a story")

            def story_playing() -> Stamped | None:
                graph.check()
                status = bench.new_stream(known)
                if status is None:
                    return None
                return next(
                    (
                        s
                        for s in bench.statuses_of(status.msg.stream_id)
                        if s.msg.played_ms >= PLAYED_BEFORE_MS
                    ),
                    None,
                )

            story = wait_until(story_playing, 30, f"trial {trial}: the story playing")
            stream_id = story.msg.stream_id
            known.add(stream_id)
            pcm = speech_like(0.5, trial)
            pieces = [pcm[k : k + chunk] for k in range(0, len(pcm), chunk)]
            utterance = bench.new_utterance()
            onset = time.monotonic()
            bench.say_activity(True)
            bench.voice.publish(bench.chunk(pieces[0], utterance, 0, False))

            def silent(stream: str = stream_id) -> Stamped | None:
                graph.check()
                return next(
                    (s for s in bench.statuses_of(stream) if s.msg.interrupted and not s.msg.speaking),
                    None,
                )

            cut = wait_until(silent, 10, f"trial {trial}: the player silent")
            for sequence, piece in enumerate(pieces[1:], start=1):
                time.sleep(CHUNK_MS / 1000)  # the rest of the utterance, paced like the VAD
                bench.voice.publish(bench.chunk(piece, utterance, sequence, sequence == len(pieces) - 1))
            bench.say_activity(False)

            def answered() -> bool:
                graph.check()
                status = bench.new_stream(known)
                if status is None:
                    return False
                known.add(status.msg.stream_id)
                return True

            wait_until(answered, 30, f"trial {trial}: the answer to the interruption")
            if trial:
                latencies.append(1000 * (cut.at - onset))
        types = graph.emulator.received_types()
    # Each barge-in reached the model: a truncation (OpenAI), an activity the interruption opened
    # and the held utterance filled (Gemini).
    cuts = types.count("activityStart" if provider == "gemini" else "conversation.item.truncate")
    assert cuts == trials + 1, f"{cuts} cuts at the {provider} emulator for {trials + 1} barge-ins"
    return latencies


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--provider", choices=(*PROVIDERS, "all"), default="all")
    args = parser.parse_args()
    providers = PROVIDERS if args.provider == "all" else (args.provider,)
    measured = {provider: measure(provider, args.trials) for provider in providers}

    dds = dds_one_way_ms(args.trials * 2, speech_like(CHUNK_MS / 1000, 99))
    ws = websocket_round_trip_ms(args.trials * 2, speech_like(CHUNK_MS / 1000, 99))
    floor = 3 * percentile(dds, 50) + percentile(ws, 50)
    for name, values in {
        "baseline_dds_publish_to_subscribe_ms": dds,
        "baseline_websocket_round_trip_ms": ws,
    }.items():
        print(json.dumps({"bench": "barge_in", "figure": name, **summary(values)}))
    rows: list[tuple[str, list[float], str]] = []
    for provider, latencies in measured.items():
        print(
            json.dumps(
                {
                    "bench": "barge_in",
                    "provider": provider,
                    "figure": "speech_onset_to_player_silent_ms",
                    **summary(latencies),
                }
            )
        )
        print(
            json.dumps(
                {
                    "bench": "barge_in",
                    "provider": provider,
                    "figure": "barge_in_vs_transport_floor",
                    "p50_ratio_vs_floor": round(percentile(latencies, 50) / floor, 2),
                    "floor_ms": round(floor, 2),
                    "player_block_ms": BLOCK_MS,
                    "goal_p95_ms": GOAL_P95_MS,
                    "meets_goal": percentile(latencies, 95) <= GOAL_P95_MS,
                }
            )
        )
        rows += [
            (f"{provider}: speech onset -> player silent", latencies, f"goal p95 <= {GOAL_P95_MS:g} ms"),
            (f"{provider}: / transport floor", [percentile(latencies, 50) / floor], "ratio of p50s (not ms)"),
        ]
    rows += [
        ("baseline: DDS publish -> subscribe", dds, "one hop"),
        ("baseline: WebSocket round trip", ws, "one round trip"),
        ("transport floor (3 DDS + 1 WS)", [floor], "3 x DDS p50 + 1 x WS p50"),
    ]
    table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
