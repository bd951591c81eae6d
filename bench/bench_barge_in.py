"""Barge-in latency (issue 9; goal <= 150 ms p95): the user's speech onset in the microphone stream
(voice_activity True and the first chunk of the interrupting utterance published) → the player
silent for the reply it was playing (its playback_status for that stream: interrupted, not
speaking).

Real processes: ros_ai_bridge, simple_audio_player (real-time WAV sink, 20 ms blocks), `byc agent`
(echo_mode external: full duplex) → the OpenAI emulator on a thread here. Each trial: a typed
question, a 6 s story playing; after 300 ms of it the bench "speaks" 500 ms (chunks every 100 ms
like the VAD), which confirms the barge-in; the agent cancels and truncates the story, commits the
utterance and the short answer plays; then the next trial.

The path crosses 3 DDS hops (bench→bridge, bridge→player, player→bench) and one WebSocket round
trip (bridge→agent→bridge), plus at most one player block: the same-run baselines (a raw DDS
publish→subscribe, a raw WebSocket round trip) give that floor.

    scripts/run.sh python bench/bench_barge_in.py [--trials N]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _agent_bench import (  # noqa: E402
    CHUNK_MS,
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

from by_your_command.emulators.openai_script import Say, Script, Turn  # noqa: E402

GOAL_P95_MS = 150.0
PLAYED_BEFORE_MS = 300
STORY = "Once upon a time a robot told a very long story about everything it saw." * 2  # ~6 s
BLOCK_MS = 20  # the player's default block


def speech_like(seconds: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * VAD_RATE)) / VAD_RATE
    return (4000 * np.sin(2 * np.pi * 200 * t) + rng.normal(0, 300, len(t))).astype(np.int16)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=20)
    args = parser.parse_args()
    chunk = VAD_RATE * CHUNK_MS // 1000
    turns = tuple(turn for _ in range(args.trials + 1) for turn in (Turn(Say(STORY)), Turn(Say("Yes?"))))
    script = Script(turns=turns, pace=0.0, ms_per_char=40)
    latencies: list[float] = []
    settings = {"echo_mode": "external", "min_barge_in_ms": 400, "barge_in_window_s": 2.0}
    with agent_graph(script, "barge_in", **settings) as graph:
        bench = graph.bench
        known: set[str] = set()
        for trial in range(args.trials + 1):  # the first one warms up
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
    truncations = types.count("conversation.item.truncate")
    assert truncations == args.trials + 1, f"{truncations} truncations for {args.trials + 1} barge-ins"

    dds = dds_one_way_ms(args.trials * 2, speech_like(CHUNK_MS / 1000, 99))
    ws = websocket_round_trip_ms(args.trials * 2, speech_like(CHUNK_MS / 1000, 99))
    floor = 3 * percentile(dds, 50) + percentile(ws, 50)
    p95 = percentile(latencies, 95)
    for name, values in {
        "speech_onset_to_player_silent_ms": latencies,
        "baseline_dds_publish_to_subscribe_ms": dds,
        "baseline_websocket_round_trip_ms": ws,
    }.items():
        print(json.dumps({"bench": "barge_in", "figure": name, **summary(values)}))
    print(
        json.dumps(
            {
                "bench": "barge_in",
                "figure": "barge_in_vs_transport_floor",
                "p50_ratio_vs_floor": round(percentile(latencies, 50) / floor, 2),
                "floor_ms": round(floor, 2),
                "player_block_ms": BLOCK_MS,
                "goal_p95_ms": GOAL_P95_MS,
                "meets_goal": p95 <= GOAL_P95_MS,
            }
        )
    )
    table(
        [
            ("speech onset -> player silent (the figure)", latencies, f"goal p95 <= {GOAL_P95_MS:g} ms"),
            ("baseline: DDS publish -> subscribe", dds, "one hop"),
            ("baseline: WebSocket round trip", ws, "one round trip"),
            (
                "transport floor (3 DDS + 1 WS)",
                [floor],
                f"p50 = {percentile(latencies, 50) / floor:.1f}x floor",
            ),
        ]
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
