"""Soak: an hour of conversation, compressed, through the whole cloud graph; memory, CPU, losses.

The oai_realtime profile (`byc up`: file source → echo control → VAD → bridge → OpenAI agent →
player WAV sink + command processor) plays a long speech file faster than real time to an agent
served by the OpenAI Realtime emulator (`byc emulate openai`), with session cycling on (the
profile's pause_timeout): short gaps keep the session, a long pause in every round closes it, and
the next utterance reopens it. Every `--sample-s` the resident memory and CPU time of each process
of the graph is read from /proc.

Reported (JSON lines, then a table): utterances played, cut by the VAD, and turns the agent
recorded (completed, failed, other) — an utterance the VAD cut that became no turn record and was
not reported unheard by the VAD is a silent loss; per process, RSS
at the start of the second half and at the end, its least-squares slope over the second half
(the first half includes warm-up: allocator pools, DDS discovery), and mean CPU; billed session
seconds against spoken seconds (both in wall time: the file plays `--rate` times faster).

usage: scripts/run.sh python bench/soak.py [--minutes 60] [--rate 4] [--sample-s 5] [--out DIR]
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import json
import os
import re
import socket
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from _proc import Series, process_names, sample_tree

from by_your_command.audio.pcm import read_wav, write_wav
from by_your_command.bridge.client import BridgeClient, ClientOptions
from by_your_command.bridge.client_messages import Lost, Received
from by_your_command.demo.child import ChildGraph

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "by_your_command" / "test" / "data" / "corpus"
RATE = 16000
# Gaps in audio time. At --rate 4 the echo gate holds the microphone closed for the reply's wall
# time (latency + playback + tail, about 1.3 s) = about 5 s of audio: a gap must be longer than that
# or the next utterance is gated (half duplex by design). Short gaps keep the session open (under
# pause_timeout × rate); the long pause at the end of a round closes it and the next voice reopens.
SHORT_GAP_S = 7.0
LONG_PAUSE_S = 16.0
AUDIO_BLOCK = 512  # samples per AudioChunk of the file source (its default chunk_samples)
SCRIPT = {"pace": 1.0, "ms_per_char": 40, "default_reply": {"say": "Okay, noted."}}


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    print(json.dumps({"bench": "soak", "figure": figure, "value": round(value, 4), "unit": unit, **extra}))


# --- the speech --------------------------------------------------------------------------------


def make_speech(path: Path, minutes: float) -> tuple[int, float]:
    """Rounds of the corpus's clean utterances until `minutes` of audio; (utterances, speech s)."""
    segments = json.loads((CORPUS / "segments.json").read_text())["sessions"]["clean_en_us"]["segments"]
    samples, rate, _ = read_wav(CORPUS / "clean_en_us.wav")
    assert rate == RATE
    clips = [samples[int(s["start"] * rate) : int(s["end"] * rate)] for s in segments]
    short_gap = np.zeros(int(SHORT_GAP_S * RATE), np.int16)
    long_pause = np.zeros(int(LONG_PAUSE_S * RATE), np.int16)
    one_round: list[np.ndarray] = []
    for index, clip in enumerate(clips):
        one_round += [clip, long_pause if index == len(clips) - 1 else short_gap]
    round_pcm = np.concatenate(one_round)
    rounds = max(1, round(minutes * 60 * RATE / len(round_pcm)))
    write_wav(path, np.tile(round_pcm, rounds), RATE)
    return rounds * len(clips), rounds * sum(len(c) for c in clips) / RATE


# --- /proc sampling ----------------------------------------------------------------------------


_VAD_STATS = re.compile(r"\[silero_vad_node\s*\].* utterances=(\d+) .*unheard_utterances=(\d+)")


def vad_counts(graph_log: Path) -> tuple[int, int]:
    """(utterances, unheard) from the VAD's last stats line: what it cut, and what nobody heard."""
    found = _VAD_STATS.findall(graph_log.read_text(errors="replace")) if graph_log.exists() else []
    return (int(found[-1][0]), int(found[-1][1])) if found else (0, 0)


# --- the run -----------------------------------------------------------------------------------


@dataclass
class Tally:
    outcomes: collections.Counter[str] = field(default_factory=collections.Counter)
    billed_s: float = 0.0
    sessions: int = 0
    close_reasons: collections.Counter[str] = field(default_factory=collections.Counter)
    lost_reports: int = 0
    file_done: bool = False
    last_record_at: float = 0.0

    def feed(self, topic: str, msg: dict[str, Any], now: float) -> None:
        if topic.endswith("file_audio_done"):
            self.file_done = self.file_done or bool(msg.get("data"))
            return
        try:
            record = json.loads(msg.get("data", ""))
        except (TypeError, ValueError):
            return
        self.last_record_at = now
        if record.get("record") == "turn":
            self.outcomes[str(record.get("outcome"))] += 1
        elif record.get("record") == "session":
            self.sessions += 1
            self.billed_s += float(record.get("billed_s", 0.0))
            self.close_reasons[str(record.get("close_reason", ""))[:40]] += 1


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


async def _start_emulator(workdir: Path) -> tuple[asyncio.subprocess.Process, str]:
    script = workdir / "script.yaml"
    script.write_text(yaml.safe_dump(SCRIPT))
    emulator = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "by_your_command.cli.byc", "emulate", "openai", "--port", "0",
        "--script", str(script), stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
    )  # fmt: skip
    assert emulator.stdout is not None
    while True:
        line = (await asyncio.wait_for(emulator.stdout.readline(), 30)).decode()
        if not line:
            raise RuntimeError("the emulator exited before listening")
        if found := re.search(r"OPENAI_BASE_URL=(\S+)", line):
            return emulator, found[1]


async def soak(args: argparse.Namespace, workdir: Path) -> int:
    speech = workdir / "soak_speech.wav"
    utterances, speech_s = make_speech(speech, args.minutes)
    audio_s = len(read_wav(speech)[0]) / RATE
    print(f"speech: {utterances} utterances, {speech_s:.0f} s of speech in {audio_s:.0f} s of audio")
    emulator, base_url = await _start_emulator(workdir)
    os.environ.update({"OPENAI_API_KEY": "sk-emulator", "OPENAI_BASE_URL": base_url})
    port = _free_port()
    sets = {
        "audio_source": f"file:{speech}",
        "audio_sink": f"wav:{workdir / 'robot_said.wav'}",
        "bridge_port": str(port),
        "file_audio_publisher.rate_factor": str(args.rate),
        "simple_audio_player.realtime": "false",  # replies do not hold the echo gate for real time
    }
    # A namespace of its own: another graph on this machine (a test, a demo) must not cross-talk.
    argv = [sys.executable, "-m", "by_your_command.cli.up", "oai_realtime", "--stop-timeout", "20"]
    argv += ["--namespace", f"bench_{os.getpid()}"]
    for key, value in sets.items():
        argv += ["--set", f"{key}={value}"]
    child = ChildGraph(argv, workdir / "graph.log")
    tally = Tally()
    series: dict[int, Series] = {}
    started = time.monotonic()
    deadline = started + audio_s / args.rate + 120.0
    next_sample = started
    status = 0
    try:
        await child.start()
        assert child.pid is not None
        options = ClientOptions(backoff_initial_s=0.1, backoff_max_s=0.5)
        async with BridgeClient(f"ws://127.0.0.1:{port}", options) as client:
            await client.subscribe("agent_metrics", "std_msgs/msg/String", topic_class="text")
            await client.subscribe("file_audio_done", "std_msgs/msg/Bool", topic_class="state")
            while True:
                now = time.monotonic()
                if now >= next_sample:
                    sample_tree(child.pid, now - started, series)
                    next_sample += args.sample_s
                if child.exited:
                    print(f"FAILED: {child.what_failed()}", file=sys.stderr)
                    status = 1
                    break
                if tally.file_done and now - tally.last_record_at > 10.0:
                    break
                if now > deadline:
                    print("FAILED: the file did not end in time", file=sys.stderr)
                    status = 1
                    break
                try:
                    delivery = await client.receive(timeout=0.5)
                except TimeoutError:
                    continue
                if isinstance(delivery, Lost):
                    tally.lost_reports += 1
                    continue
                if isinstance(delivery, Received):  # (the soak makes no service calls)
                    tally.feed(delivery.topic, delivery.msg, now)
    finally:
        wall_s = time.monotonic() - started
        await child.stop(25.0)
        emulator.terminate()
        await emulator.wait()
    names = {**process_names(child.log_path), child.pid: "byc up"}
    named = {f"{names.get(pid, 'other')}[{pid}]": entry for pid, entry in series.items()}
    report(tally, named, utterances, vad_counts(child.log_path), speech_s / args.rate, wall_s, args)
    return status


def _slope_mb_per_h(times: list[float], values: list[float]) -> float:
    if len(times) < 3:
        return float("nan")
    slope = np.polyfit(np.asarray(times), np.asarray(values), 1)[0]
    return float(slope) * 3600.0


def report(
    tally: Tally,
    series: dict[str, Series],
    utterances: int,
    vad: tuple[int, int],
    spoken_wall_s: float,
    wall_s: float,
    args: Any,
) -> None:
    answered = tally.outcomes["completed"]
    recorded = sum(tally.outcomes.values())
    cut, unheard = vad
    emit("utterances_played", utterances, "count")
    # More than played: the echo gate split one (half duplex); fewer: the VAD missed or merged some.
    emit("utterances_cut_by_vad", cut, "count")
    emit("utterances_reported_unheard", unheard, "count")
    emit("turns_completed", answered, "count")
    emit("turns_reported_not_completed", recorded - answered, "count", outcomes=dict(tally.outcomes))
    # What the VAD cut must reach the agent as a turn (any outcome) or be reported unheard.
    emit("silent_losses", max(0, cut - unheard - recorded), "count")
    emit("lost_reports", tally.lost_reports, "count")
    emit("sessions", tally.sessions, "count", close_reasons=dict(tally.close_reasons))
    emit("billed_session_s", tally.billed_s, "s")
    emit("spoken_s_wall", spoken_wall_s, "s")
    emit("billed_per_spoken", tally.billed_s / spoken_wall_s if spoken_wall_s else float("nan"), "ratio")
    emit("wall_s", wall_s, "s", audio_minutes=args.minutes, rate=args.rate)
    print(f"\n{'process':34} {'RSS mid MB':>10} {'RSS end MB':>10} {'MB/h 2nd half':>13} {'CPU %':>6}")
    for name, entry in sorted(series.items()):
        if len(entry.times) < 4:
            continue
        half = len(entry.times) // 2
        slope = _slope_mb_per_h(entry.times[half:], entry.rss_mb[half:])
        cpu = entry.cpu_percent()
        last = len(entry.rss_mb) - 1
        quarters = [round(entry.rss_mb[last * q // 4], 1) for q in range(5)]  # growth, or a plateau?
        # Per block of the audio stream (512 samples), comparable with bench_memory.py's figure.
        per_block = slope * 2**20 / (RATE / AUDIO_BLOCK * args.rate * 3600)
        emit(
            "rss_slope",
            slope,
            "MB/h",
            process=name,
            rss_quarters_mb=quarters,
            bytes_per_audio_block=round(per_block) if np.isfinite(per_block) else None,
        )
        emit("cpu", cpu, "% of one core", process=name)
        print(f"{name:34} {entry.rss_mb[half]:10.1f} {entry.rss_mb[-1]:10.1f} {slope:13.2f} {cpu:6.1f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=60.0, help="minutes of conversation audio")
    parser.add_argument("--rate", type=float, default=4.0, help="how much faster than real time")
    parser.add_argument("--sample-s", type=float, default=5.0, help="seconds between /proc samples")
    parser.add_argument("--out", type=Path, help="keep the speech, replies and graph log here")
    args = parser.parse_args()
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        return asyncio.run(soak(args, args.out))
    with tempfile.TemporaryDirectory(prefix="byc-soak-") as workdir:
        return asyncio.run(soak(args, Path(workdir)))


if __name__ == "__main__":
    sys.exit(main())
