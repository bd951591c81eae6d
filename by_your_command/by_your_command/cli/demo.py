"""`byc demo`: the voice demo through the real graph, narrated live (also `make demo`).

    byc demo                          # offline agent, bundled speech; --out DIR: where results go
    byc demo --provider openai        # OpenAI Realtime (OPENAI_API_KEY): mic + speaker if present
    byc demo --provider gpt-live      # OpenAI GPT-Live, full duplex (OPENAI_API_KEY; echo cancelled)
    byc demo --input my.wav --out /tmp/demo

Starts the profile's graph as a child `byc up` (the same supervisor, the same graph description),
watches it through the bridge with a BridgeClient like an agent does (no ROS here), and prints what
was heard, what the robot said, which command went to which topic with the command processor's
verdict, attention changes and per-turn latency. A file-driven demo ends by itself once the file
was played and the last reply finished; the graph is stopped and a summary printed.
Exit status: 0 done and stopped cleanly; 1 a process died (named), the bridge refused us, nothing
was heard, or the deadline passed; 2 the demo cannot start (a missing key or file, a bad option).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import socket
import sys
import time
import wave
from dataclasses import dataclass
from pathlib import Path

from by_your_command.bridge.client import BridgeClient, ClientOptions, ClientStopped
from by_your_command.demo.child import ChildGraph
from by_your_command.demo.plan import PROVIDERS, DemoPlan, DemoSetupError, make_plan, mic_and_speaker_present
from by_your_command.demo.transcript import TOPICS, Narrator
from by_your_command.graph.model import Graph
from by_your_command.graph.options import parse_options
from by_your_command.graph.params import GraphError
from by_your_command.graph.profiles import PROFILES, build_graph

EXIT_OK, EXIT_FAILED, EXIT_SETUP = 0, 1, 2
STOP_TIMEOUT_S = 20.0  # byc up's SIGTERM -> SIGKILL; the demo waits a little longer for it
STARTUP_ALLOWANCE_S = 60.0  # file-driven deadline: the file's length plus this


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--provider",
        choices=list(PROVIDERS),
        default="offline",
        help="offline (default: no network, no key), openai (OPENAI_API_KEY), gemini (GEMINI_API_KEY), "
        "gpt-live (OPENAI_API_KEY)",
    )
    parser.add_argument("--input", type=Path, help="a speech WAV to play instead of the bundled one")
    parser.add_argument(
        "--out",
        type=Path,
        help="where robot_said.wav and graph.log go (default: $XDG_STATE_HOME/by_your_command/demo)",
    )
    parser.add_argument("--namespace", default="", help="run the graph in this namespace")
    parser.add_argument("--bridge-port", type=int, default=0, help="the bridge's port (0: a free one)")
    parser.add_argument(
        "--grace", type=float, default=3.0, help="quiet seconds after the file before it ends (%(default)s)"
    )
    parser.add_argument("--timeout", type=float, help="give up after this many seconds (default: file + 60)")
    parser.add_argument("--verbose", "-v", action="store_true", help="also print every node's log lines")


def _say(text: str) -> None:
    print(f"byc demo: {text}", flush=True)


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _wav_seconds(path: Path | None) -> float | None:
    if path is None:
        return None
    try:
        with wave.open(str(path), "rb") as wav:
            return wav.getnframes() / float(wav.getframerate())
    except (OSError, EOFError, wave.Error):
        return None


def _build(plan: DemoPlan, namespace: str, port: int) -> tuple[Graph, list[str]]:
    """The graph (checked here, so a wrong value stops before anything starts) and byc up's argv."""
    values = {
        "audio_source": plan.audio_source,
        "audio_sink": plan.audio_sink,
        "bridge_port": str(port),
        "namespace": namespace,
    }
    profile = plan.provider.profile
    graph = build_graph(profile, parse_options(values, PROFILES[profile].defaults))
    argv = [sys.executable, "-m", "by_your_command.cli.up", profile]
    for key, value in values.items():
        argv += ["--set", f"{key}={value}"]
    return graph, [*argv, "--stop-timeout", str(STOP_TIMEOUT_S)]


@dataclass
class Outcome:
    status: int = EXIT_OK
    reason: str = ""


async def _watch(
    plan: DemoPlan, child: ChildGraph, narrator: Narrator, url: str, args: argparse.Namespace
) -> Outcome:
    """Narrate until the demo is over; the graph is still running (or dead) when this returns."""
    started = time.monotonic()
    speech_s = _wav_seconds(plan.speech)
    timeout = args.timeout or ((speech_s or 60.0) + STARTUP_ALLOWANCE_S if plan.ends_by_itself else None)
    deadline = started + timeout if timeout else None
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    token = os.environ.get("BYC_BRIDGE_TOKEN", "")
    options = ClientOptions(token=token, backoff_initial_s=0.1, backoff_max_s=0.5)
    try:
        await child.start()
        _say(f"graph starting (every node's log goes to {child.log_path}); connecting to {url}")
        async with BridgeClient(url, options) as client:
            for topic, (msg_type, lane) in TOPICS.items():
                await client.subscribe(topic, msg_type, topic_class=lane)
            connected = False
            while True:
                now = time.monotonic()
                if not connected and client.connected:
                    connected = True
                    _say(f"connected to the bridge after {now - started:.1f} s; listening")
                if stop.is_set():
                    return Outcome(EXIT_OK, "stopped on request")
                if child.exited:
                    return Outcome(EXIT_FAILED, f"the graph failed: {child.what_failed()}")
                if plan.ends_by_itself and narrator.settled(now, args.grace):
                    return _judged(narrator)
                if deadline is not None and now > deadline:
                    waiting = "the file to end" if not narrator.file_done else "the last reply to finish"
                    return Outcome(EXIT_FAILED, f"gave up after {timeout:.0f} s waiting for {waiting}")
                try:
                    delivery = await client.receive(timeout=0.25)
                except TimeoutError:
                    continue
                for line in narrator.feed(delivery):
                    print(line, flush=True)
    except ClientStopped as stopped:
        hint = " (set BYC_BRIDGE_TOKEN to the bridge's token)" if "401" in str(stopped) else ""
        return Outcome(EXIT_FAILED, f"the bridge client stopped: {stopped}{hint}")
    finally:
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(signum)


def _judged(narrator: Narrator) -> Outcome:
    tally = narrator.tally
    if not (tally.heard or tally.replies or tally.routed or tally.refused):
        return Outcome(EXIT_FAILED, "the file was played but the robot heard nothing (see the graph log)")
    return Outcome(EXIT_OK, "the speech file was played and every reply finished")


def _print_summary(plan: DemoPlan, narrator: Narrator, wall_s: float) -> None:
    print("\nsummary", flush=True)
    tally = narrator.tally
    routed = ", ".join(f"{command} -> {topic}" for command, topic in tally.routed) or "none"
    refused = ", ".join(f'"{raw}" ({reason})' for raw, reason in tally.refused) or "none"
    print(f"  commands routed   {len(tally.routed)}: {routed}")
    print(f"  commands refused  {len(tally.refused)}: {refused}")
    print(f"  heard             {len(tally.heard)} utterance(s); replies {len(tally.replies)}")
    print(f"  attention         {' -> '.join(tally.attention) or 'no change seen'}")
    if tally.lost:
        print(f"  lost              {tally.lost} report(s) of lost messages")
    if plan.reply_wav is not None:
        seconds = _wav_seconds(plan.reply_wav)
        length = f"{seconds:.1f} s of audio" if seconds is not None else "not written"
        print(f"  robot's voice     {plan.reply_wav} ({length})")
    print(f"  graph log         {plan.graph_log}")
    print(f"  wall time         {wall_s:.1f} s", flush=True)


async def _run(plan: DemoPlan, args: argparse.Namespace) -> int:
    port = args.bridge_port or _free_port()
    try:
        graph, argv = _build(plan, args.namespace, port)
    except GraphError as error:
        print(f"byc demo: {error}", file=sys.stderr)
        return EXIT_SETUP
    source = f"speech from {plan.speech}" if plan.speech else "the microphone (Ctrl-C ends the demo)"
    sink = f"its voice goes to {plan.reply_wav}" if plan.reply_wav else "its voice plays on the speaker"
    _say(f"{plan.provider.label}; {source}; {sink}")
    _say(f"profile {graph.profile}: {graph.node_names()}, {', '.join(a.name for a in graph.agents)}")
    echo = (lambda line: print(f"  | {line}", flush=True)) if args.verbose else None
    child = ChildGraph(argv, plan.graph_log, echo)
    started = time.monotonic()
    narrator = Narrator(graph.namespace, started)
    outcome = await _watch(plan, child, narrator, f"ws://127.0.0.1:{port}", args)
    died_first = child.exited
    stopped = await child.stop(STOP_TIMEOUT_S + 5.0)
    if died_first and stopped == EXIT_SETUP:  # byc up refused the graph before starting anything
        print("byc demo: the graph could not start:\n" + "\n".join(child.tail), file=sys.stderr)
        return EXIT_SETUP
    if not died_first and stopped != 0 and outcome.status == EXIT_OK:
        outcome = Outcome(EXIT_FAILED, f"the graph did not stop cleanly: {child.what_failed()}")
    _print_summary(plan, narrator, time.monotonic() - started)
    if outcome.status != EXIT_OK:
        print(f"byc demo: FAILED: {outcome.reason}", file=sys.stderr)
        print("last lines of the graph log:\n  " + "\n  ".join(child.tail), file=sys.stderr)
        return outcome.status
    _say(f"done: {outcome.reason}")
    return EXIT_OK


def run(args: argparse.Namespace) -> int:
    try:
        plan = make_plan(args.provider, args.input, args.out, os.environ, mic_and_speaker_present)
    except DemoSetupError as error:
        print(f"byc demo: {error}", file=sys.stderr)
        return EXIT_SETUP
    return asyncio.run(_run(plan, args))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="byc demo", description="the voice demo through the real graph")
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
