"""Billed realtime-session seconds for a simulated hour with 10 short exchanges (issue 9).

The real `AgentRuntime` with the scripted fake provider on virtual time (by_your_command/test/agents:
virtual_time, fake_provider, fake_port), so an hour takes about a second. Each exchange: the user
speaks (VAD chunks every 100 ms, voice_activity around them), the model answers after 0.5 s,
generating audio 4x faster than real time, a simulated player plays it in real time and reports
`playback_status` at 10 Hz like simple_audio_player; every other exchange has a follow-up question
1.5 s after the reply. Connecting takes 0.3 s (billed: billing runs from connect start to close).

Figures per `pause_timeout_s` (the default and others): billed seconds (sum of the sessions'
SessionMetrics), the conversation's seconds (first speech onset to the end of the last reply's
playback, per exchange), the goal (<= 1.1 x conversation + 2 s per exchange) and, as the baseline
measured in the same run, no pause cycling (one session, closed only by the rotation before the
provider's 60-minute limit).

GPT-Live (billed every second of open session, issue 36) runs the runtime's full-duplex path with a
sweep of pauses around agent_gpt_live.yaml's (1, 2, 3, 5, 10 s and the configured one), its goal
(<= 1.2 x conversation + 3 s per conversation) and its own no-cycling baseline.

    scripts/run.sh python bench/bench_billing.py
"""

from __future__ import annotations

import asyncio
import json
import random
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "by_your_command" / "test" / "agents"))

from fake_port import FakePort, running_agent, speak  # type: ignore[import-not-found]  # noqa: E402
from fake_provider import FakeFactory, spoken_reply  # type: ignore[import-not-found]  # noqa: E402
from virtual_time import run_virtual  # type: ignore[import-not-found]  # noqa: E402

from by_your_command.agents.app_config import load_app_config  # noqa: E402
from by_your_command.agents.config import AgentConfig, EchoMode  # noqa: E402
from by_your_command.agents.inputs import PlaybackStatus, VoiceActivity  # noqa: E402
from by_your_command.agents.port import VoiceChunk  # noqa: E402

HOUR_S = 3600.0
EXCHANGES = 10
CONNECT_S = 0.3
MODEL_DELAY_S = 0.5
STATUS_PERIOD_S = 0.1
FOLLOW_UP_GAP_S = 1.5
PAUSES_S = (10.0, 1.0, 2.0, 5.0, 30.0)  # the default (AgentConfig.pause_timeout_s) first
NEVER_S = 2 * HOUR_S  # baseline: no cycling within the hour
# GPT-Live bills every second of open session (issue 36): <= 1.2 x conversation + 3 s per conversation.
GPT_LIVE_GOAL_RATIO = 1.2
GPT_LIVE_GOAL_S_PER_CONVERSATION = 3.0
GPT_LIVE_PAUSES_S = (1.0, 2.0, 3.0, 5.0, 10.0)  # swept with agent_gpt_live.yaml's own pause
GPT_LIVE_USD_PER_HOUR = 3.0


@dataclass(frozen=True)
class Turn:
    speech_s: float
    reply_s: float


@dataclass(frozen=True)
class Exchange:
    start_s: float
    turns: tuple[Turn, ...]


@dataclass(frozen=True)
class Result:
    pause_s: float
    billed_s: float
    conversation_s: float
    sessions: int
    turns_completed: int


def exchanges(seed: int = 9) -> list[Exchange]:
    """10 exchanges spread over the hour (jittered), 1 or 2 turns each, short speech and replies."""
    rng = random.Random(seed)
    spacing = HOUR_S / EXCHANGES
    found = []
    for k in range(EXCHANGES):
        turns = tuple(
            Turn(round(rng.uniform(1.0, 3.0), 1), round(rng.uniform(1.5, 5.0), 1)) for _ in range(1 + k % 2)
        )
        found.append(Exchange(k * spacing + rng.uniform(20.0, spacing - 60.0), turns))
    return found


async def play(port: Any, published_before: int, now: Any) -> float:
    """Play the next reply like simple_audio_player: real time, status at 10 Hz, `finished` at the
    end of its last sample; returns when it ended."""
    stream_id = ""
    received_s = 0.0
    ended = False
    started_at = 0.0
    seen = published_before
    while True:
        chunks: list[VoiceChunk] = port.voice()[seen:]
        seen += len(chunks)
        for chunk in chunks:
            if not stream_id:
                stream_id, started_at = chunk.stream_id, now()
            received_s += len(chunk.pcm) / 2 / chunk.sample_rate
            ended = ended or chunk.end_of_stream
        if stream_id:
            played_s = min(received_s, now() - started_at)
            queued_ms = int(1000 * (received_s - played_s))
            if ended and played_s >= received_s:
                port.push(PlaybackStatus(stream_id, int(1000 * received_s), 0, False, True))
                return float(started_at + received_s)
            port.push(PlaybackStatus(stream_id, int(1000 * played_s), queued_ms, speaking=True))
        await asyncio.sleep(STATUS_PERIOD_S)


async def hour(pause_s: float, duplex: bool = False) -> Result:
    plan = exchanges()
    scripts = [
        spoken_reply(f"r{e}-{t}", seconds=turn.reply_s, first_after_s=MODEL_DELAY_S, pace_s=0.05)
        for e, exchange in enumerate(plan)
        for t, turn in enumerate(exchange.turns)
    ]

    def slow_connect(provider: Any, index: int) -> None:
        provider.connect_delay_s = CONNECT_S
        provider.duplex = duplex  # GPT-Live: the runtime's full-duplex path

    factory = FakeFactory(*scripts, configure=slow_connect)
    config = replace(AgentConfig(), pause_timeout_s=pause_s, conversation_timeout_s=2 * HOUR_S)
    if duplex:
        config = replace(config, echo_mode=EchoMode.AEC)
    loop = asyncio.get_running_loop()
    conversation_s = 0.0
    async with running_agent(config, factory) as agent:
        port: FakePort = agent.port
        utterance = 0
        for exchange in plan:
            await asyncio.sleep(max(0.0, exchange.start_s - loop.time()))
            began = loop.time()
            for index, turn in enumerate(exchange.turns):
                if index:
                    await asyncio.sleep(FOLLOW_UP_GAP_S)
                utterance += 1
                before = len(port.voice())
                port.push(VoiceActivity(True))
                await speak(port, utterance, turn.speech_s)
                port.push(VoiceActivity(False))
                ended = await play(port, before, loop.time)
            conversation_s += ended - began
        await asyncio.sleep(max(0.0, HOUR_S - loop.time()))
        await agent.stop()
        sessions = port.sessions()
        completed = sum(t.outcome == "completed" for t in port.turns())
    billed = sum(s.billed_s for s in sessions)
    return Result(pause_s, billed, conversation_s, len(sessions), completed)


def gpt_live_goal_s(conversation_s: float) -> float:
    return GPT_LIVE_GOAL_RATIO * conversation_s + GPT_LIVE_GOAL_S_PER_CONVERSATION * EXCHANGES


def gpt_live_figure(result: Result, baseline: Result, configured_pause_s: float) -> dict[str, Any]:
    """One GPT-Live JSON figure: a swept pause, or (result is baseline) no pause cycling."""
    goal_s = gpt_live_goal_s(result.conversation_s)
    is_baseline = result is baseline
    return {
        "bench": "agent_billing",
        "figure": f"gpt_live_billed_session_s_per_hour{'_without_cycling' if is_baseline else ''}",
        "pause_timeout_s": None if is_baseline else result.pause_s,
        "configured": not is_baseline and result.pause_s == configured_pause_s,  # agent_gpt_live.yaml's
        "sessions": result.sessions,
        "turns_completed": result.turns_completed,
        "billed_s": round(result.billed_s, 1),
        "conversation_s": round(result.conversation_s, 1),
        "billed_ratio_vs_conversation": round(result.billed_s / result.conversation_s, 3),
        "overhead_s_per_conversation": round((result.billed_s - result.conversation_s) / EXCHANGES, 2),
        "goal_s": round(goal_s, 1),
        "meets_goal": result.billed_s <= goal_s,
        "cost_usd_at_3_per_hour": round(result.billed_s / HOUR_S * GPT_LIVE_USD_PER_HOUR, 3),
        "baseline_billed_s": round(baseline.billed_s, 1),
        "baseline_cost_usd": round(baseline.billed_s / HOUR_S * GPT_LIVE_USD_PER_HOUR, 3),
    }


def main() -> int:
    turns = sum(len(e.turns) for e in exchanges())
    baseline = run_virtual(hour(NEVER_S), deadline_s=2 * HOUR_S)
    results = [run_virtual(hour(pause), deadline_s=2 * HOUR_S) for pause in PAUSES_S]
    live_pause = load_app_config("agent_gpt_live.yaml").agent.pause_timeout_s
    live_pauses = sorted({*GPT_LIVE_PAUSES_S, live_pause})
    live = [run_virtual(hour(pause, duplex=True), deadline_s=2 * HOUR_S) for pause in live_pauses]
    live_baseline = run_virtual(hour(NEVER_S, duplex=True), deadline_s=2 * HOUR_S)
    for result in (*live, live_baseline):
        print(json.dumps(gpt_live_figure(result, live_baseline, live_pause)))
    rows = []
    for result in (*results, baseline):
        goal_s = 1.1 * result.conversation_s + 2.0 * EXCHANGES
        is_baseline = result is baseline
        figure = {
            "bench": "agent_billing",
            "figure": "billed_session_s_per_hour",
            "pause_timeout_s": None if is_baseline else result.pause_s,
            "default": result.pause_s == AgentConfig().pause_timeout_s,
            "exchanges": EXCHANGES,
            "turns": turns,
            "turns_completed": result.turns_completed,
            "sessions": result.sessions,
            "billed_s": round(result.billed_s, 1),
            "conversation_s": round(result.conversation_s, 1),
            "billed_ratio_vs_conversation": round(result.billed_s / result.conversation_s, 3),
            "overhead_s_per_exchange": round((result.billed_s - result.conversation_s) / EXCHANGES, 2),
            "goal_s": round(goal_s, 1),
            "meets_goal": result.billed_s <= goal_s,
            "baseline": "no pause cycling",
            "baseline_billed_s": round(baseline.billed_s, 1),
            "ratio_vs_baseline": round(result.billed_s / baseline.billed_s, 4),
        }
        if is_baseline:
            figure["figure"] = "billed_session_s_per_hour_without_cycling"
        print(json.dumps(figure))
        label = "no cycling (baseline)" if is_baseline else f"pause_timeout {result.pause_s:g} s"
        if figure["default"] and not is_baseline:
            label += " (default)"
        rows.append((label, result, goal_s))
    print()
    print(
        f"{'run':30s} {'billed s':>9s} {'talk s':>7s} {'goal s':>7s} {'ratio':>6s} {'s/exch':>7s}  sessions"
    )
    for label, result, goal_s in rows:
        overhead = (result.billed_s - result.conversation_s) / EXCHANGES
        print(
            f"{label:30s} {result.billed_s:9.1f} {result.conversation_s:7.1f} {goal_s:7.1f} "
            f"{result.billed_s / result.conversation_s:6.2f} {overhead:7.2f}  {result.sessions}"
            f"{'' if result.billed_s <= goal_s else '  (over the goal)'}"
        )
    print()
    header = f"{'gpt_live (goal 1.2 x talk + 3 s each)':38s} {'billed s':>9s} {'talk s':>7s} {'goal s':>7s}"
    print(f"{header}  sessions")
    for result in (*live, live_baseline):
        if result is live_baseline:
            label = "no cycling (baseline)"
        else:
            configured = " (agent_gpt_live.yaml)" if result.pause_s == live_pause else ""
            label = f"pause {result.pause_s:g} s{configured}"
        goal_s = gpt_live_goal_s(result.conversation_s)
        over = "" if result.billed_s <= goal_s else f"  (over the goal by {result.billed_s - goal_s:.1f} s)"
        print(
            f"{label:38s} {result.billed_s:9.1f} {result.conversation_s:7.1f} {goal_s:7.1f}  "
            f"{result.sessions}{over}"
        )
    return 0 if all(r.turns_completed == turns for r in (*results, baseline, *live, live_baseline)) else 1


if __name__ == "__main__":
    sys.exit(main())
