"""Recovery after faults (issue 13): how long from a fault until the agent is reconnected and until
the next utterance is answered, against a same-run baseline (a normal turn's answer time).

The graph of test/reliability/test_faults.py, with its helpers (test/agent_process/agent_graph.py,
test/reliability/fault_graph.py): ros_ai_bridge, simple_audio_player (real-time WAV sink) and
`byc agent` as processes, the OpenAI emulator on a thread here, a probe node standing in for the
VAD (its utterances: 100 ms chunks published at once, then the end marker). Faults, each repeated
`--trials` times on one graph:

- bridge: SIGKILL the bridge, start it again at once on the same port; also how long DDS takes to
  drop the dead bridge's subscriptions (until then a VAD cannot know nobody hears it);
- agent: SIGKILL the agent mid-reply, start a new one at once (new process: interpreter, SDK, bridge
  and provider connects are all in the figure);
- drop: the provider closes the TCP connection 300 ms into a reply (1006): the turn fails, the next
  turn opens a new session;
- stall: the provider stops 300 ms into a reply; `reply_timeout_s` (3 s here) fails the turn.

"answered" = the reply text of the next utterance (published right after the fault is handled: the
restart, the failure report) reached the probe; time from the fault. Times are wall clock on a
shared 2-core machine: medians are the figure, the spread is shown.

    scripts/run.sh python bench/bench_faults.py [--trials N] [--faults bridge,agent,drop,stall]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import sys
import tempfile
import time
import uuid
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for _path in (
    "by_your_command/test",
    "by_your_command/test/agent_process",
    "by_your_command/test/reliability",
):
    sys.path.insert(0, str(REPO / _path))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

from agent_graph import (  # type: ignore[import-not-found]  # noqa: E402  (test helpers)
    GraphProbe,
    agent_config,
    agent_process,
    alive,
    bridge,
    corpus_utterance,
    emulator,
    graph_probe,
    player_process,
    setup_requests,
    until,
)
from fault_graph import failures  # type: ignore[import-not-found]  # noqa: E402

from by_your_command.emulators.openai_script import Say, Script, Turn  # noqa: E402

WAIT_S = 90.0
STORY = "Once upon a time there was a robot who loved to talk about everything it saw."
MS_PER_CHAR = 40
REPLY_TIMEOUT_S = 3.0
FAULTS = ("bridge", "agent", "drop", "stall")


def since(start: float) -> float:
    return (time.monotonic() - start) * 1000.0


def ask(probe: GraphProbe, check: Callable[[], None]) -> float:
    """One utterance; ms until its reply text arrived."""
    before = len(probe.replies)
    start = time.monotonic()
    probe.say(corpus_utterance(1))
    until(lambda: len(probe.replies) > before, "the answer", check, WAIT_S)
    return since(start)


def run_fault(fault: str, trials: int, tmp: Path) -> dict[str, list[float]]:
    figures: dict[str, list[float]] = {}

    def add(name: str, value: float) -> None:
        figures.setdefault(name, []).append(value)

    turns: list[Turn] = [Turn(Say("Back."))] * trials  # the same reply as after each fault
    for _ in range(trials):
        if fault == "drop":
            turns += [Turn(Say(STORY), drop_after_ms=300), Turn(Say("Back."))]
        elif fault == "stall":
            turns += [Turn(Say(STORY), stall_after_ms=300), Turn(Say("Back."))]
        else:
            turns += [Turn(Say(STORY)), Turn(Say("Back."))]
    script = Script(turns=tuple(turns), ms_per_char=MS_PER_CHAR, pace=1.0)
    namespace = f"/bench_faults_{uuid.uuid4().hex[:8]}"
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(namespace))
        player = stack.enter_context(player_process(namespace, tmp / f"{fault}.wav"))
        probe.wait_nodes(alive(player), player=True)
        running = stack.enter_context(bridge(namespace))
        config, settings = agent_config(tmp, openai.url, reply_timeout_s=REPLY_TIMEOUT_S)
        requests = [setup_requests(settings)]
        agent, out = stack.enter_context(agent_process(config, running.port))
        probe.wait_agents_ready(namespace, requests, WAIT_S)
        check = alive(player, agent, running.process)
        for _ in range(trials):
            add("baseline: utterance → answered", ask(probe, check))
            until(lambda: not probe.speaking[-1].data, "quiet", check, WAIT_S)

        for trial in range(trials):
            if fault == "bridge":
                connected = len([line for line in out.lines if "connected to ws://" in line])
                running.kill()
                start = time.monotonic()
                if trial == trials - 1:  # the last kill: how long a VAD still sees the dead subscriber
                    until(
                        lambda: probe.voice.get_subscription_count() == 0,
                        "DDS drops it",
                        lambda: None,
                        WAIT_S,
                    )
                    add("bridge killed → DDS drops its subscriptions", since(start))
                    start = time.monotonic()
                running = stack.enter_context(bridge(namespace, running.port))
                check = alive(player, agent, running.process)
                until(
                    lambda n=connected, o=out: (
                        len([line for line in o.lines if "connected to ws://" in line]) > n
                    ),
                    "the agent reconnected",
                    check,
                    WAIT_S,
                )
                add("bridge killed → agent reconnected", since(start))
                probe.diagnostics.clear()
                probe.wait_agents_ready(namespace, requests, WAIT_S)
                add("bridge killed → next utterance answered", since(start) + ask(probe, check))
                until(lambda: not probe.speaking[-1].data, "quiet", check, WAIT_S)
            elif fault == "agent":
                probe.say(corpus_utterance(0))
                until(
                    lambda: any(s.speaking and s.played_ms > 0 for s in probe.playback[-3:]),
                    "",
                    check,
                    WAIT_S,
                )
                stream = next(s.stream_id for s in reversed(probe.playback) if s.speaking)
                agent.send_signal(signal.SIGKILL)
                agent.wait(10)
                start = time.monotonic()
                check = alive(player, running.process)
                until(
                    lambda s=stream: (
                        (last := [x for x in probe.playback if x.stream_id == s][-1])
                        and not last.speaking
                        and (last.starved or last.finished)
                    ),
                    "the dead agent's stream reported",
                    check,
                    WAIT_S,
                )
                until(lambda: not probe.speaking[-1].data, "quiet", check, WAIT_S)
                add("agent killed → player silent, its stream reported", since(start))
                probe.diagnostics.clear()
                agent, out = stack.enter_context(agent_process(config, running.port))
                check = alive(player, agent, running.process)
                probe.wait_agents_ready(namespace, requests, WAIT_S)
                add("agent killed → new agent connected", since(start))
                add("agent killed → next utterance answered", since(start) + ask(probe, check))
                until(lambda: not probe.speaking[-1].data, "quiet", check, WAIT_S)
            else:  # drop, stall: the provider fails mid-reply
                reported = len(failures(probe))
                fault_at: list[float] = []
                opened = openai.connections()
                probe.say(corpus_utterance(0))
                until(
                    lambda: any(s.speaking for s in probe.playback[-3:]), "the story playing", check, WAIT_S
                )
                if fault == "drop":
                    until(lambda o=opened: openai.open_connections() == 0 and o, "the drop", check, WAIT_S)
                fault_at.append(time.monotonic())
                until(lambda r=reported: len(failures(probe)) > r, "the failure report", check, WAIT_S)
                name = "provider dropped (1006)" if fault == "drop" else "provider stalled"
                add(f"{name} → turn failure reported", since(fault_at[0]))
                until(lambda: not probe.speaking[-1].data, "quiet", check, WAIT_S)
                add(f"{name} → next utterance answered", since(fault_at[0]) + ask(probe, check))
                until(lambda: not probe.speaking[-1].data, "quiet", check, WAIT_S)
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--faults", default=",".join(FAULTS))
    args = parser.parse_args()
    rows: list[tuple[str, list[float]]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for fault in args.faults.split(","):
            assert fault in FAULTS, f"unknown fault {fault}: one of {FAULTS}"
            for name, values in run_fault(fault, args.trials, Path(tmp)).items():
                label = f"{fault}: {name}"
                rows.append((label, values))
                median = round(statistics.median(values), 1)
                print(
                    json.dumps(
                        {"bench": "faults", "figure": label, "value": median, "unit": "ms", "n": len(values)}
                    )
                )
                sys.stdout.flush()
    print()
    print(f"{'figure':62s} {'n':>3s} {'median ms':>10s} {'min ms':>8s} {'max ms':>8s}")
    for label, values in rows:
        median, low, high = statistics.median(values), min(values), max(values)
        print(f"{label:62s} {len(values):3d} {median:10.0f} {low:8.0f} {high:8.0f}")


if __name__ == "__main__":
    main()
