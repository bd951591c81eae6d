"""End of turn: false cut-offs and latency of each rule, on speech with 300-900 ms mid-sentence pauses.

Corpus, made at run time with espeak-ng: sentences with pauses where people hesitate or list
("go to the | kitchen", "I want | um | the green one"), several voices and rates, each pause set to
an exact length from 300 to 900 ms, over a faint noise bed; the same sentences without pauses are
the control. The real VAD runs on them (VoiceDetector with Silero, 64 ms blocks as the node gets);
its per-frame probabilities are then replayed through the real Segmenter for each rule:

- silence N ms: the segmenter alone with min_silence_duration_ms = N (250 is the default);
- smart turn @N: the segmenter at N ms, then vad/end_of_turn.py asks Smart Turn v3 at each utterance
  end; 'not finished' waits until 3 s of silence in all. Needs the model file: --smart-turn PATH,
  or pipecat-ai installed (`pip install --no-deps pipecat-ai`); otherwise those rules are skipped.

A false cut-off is a turn end decided before the last word ends (inside a pause). Latency is from
the end of the last word (last sample above the noise bed in espeak's output) to the decision: the
arrival of the frame that decided it, plus the model's measured inference time.

    scripts/run.sh python bench/bench_end_of_turn.py [--smart-turn PATH] [--quick]
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
import numpy.typing as npt

from by_your_command.audio.pcm import Int16Array, resample
from by_your_command.vad.config import VadConfig
from by_your_command.vad.detector import VoiceDetector
from by_your_command.vad.end_of_turn import (
    EndOfTurn,
    EndOfTurnConfig,
    ModelNotFoundError,
    SmartTurnModel,
    bundled_model_path,
)
from by_your_command.vad.model import SileroModel
from by_your_command.vad.segmenter import FRAME_SAMPLES, Frame, Segmenter, VoiceActivity

RATE = 16000
NS_PER_S = 1_000_000_000
FRAME_NS = FRAME_SAMPLES * NS_PER_S // RATE  # 32 ms
BLOCK = 1024  # 64 ms blocks, audio_capture's default chunk
LEAD_S, TAIL_S = 1.0, 4.0  # noise before the sentence; after it (room for a 3 s wait)
NOISE_STD = 40.0  # faint noise bed, about -58 dBFS
SILENT = 60  # |sample| below this (after espeak, before the noise) is silence
PAUSES_MS = (300, 450, 600, 750, 900)
SENTENCES = (  # "|" marks a mid-sentence pause
    "go to the | kitchen",
    "bring me the red cup | and the blue plate",
    "turn left | then go forward | two meters",
    "I want | um | the green one",
    "pick up the apple, | the banana, | and the orange",
    "can you | look at the door",
    "move the chair | to the | window",
    "what do you see | on the table",
    "put it | next to the lamp",
    "tell me | what time it is",
)
VOICES = ("en-us", "en-gb", "en-us+f3", "en-gb-scotland", "en-us+m3")
SPEEDS = (140, 175, 210)
SILENCE_RULES_MS = (250, 400, 500, 700, 1000, 1200)
SMART_TURN_AT_MS = (250, 160)
TOTAL_SILENCE_MS = 3000  # smart turn's 'not finished' waits up to this much silence in all


@dataclass
class Clip:
    name: str
    pcm: Int16Array
    speech_start: float  # s
    last_word_end: float  # s
    pauses: list[tuple[float, float, int]]  # (start s, end s, nominal ms)
    probabilities: list[float] = field(default_factory=list)


def speak(text: str, voice: str, speed: int) -> Int16Array:
    """espeak-ng with SSML breaks (the sentence keeps one intonation across a pause), 16 kHz."""
    ssml = "<speak>" + ' <break time="700ms"/> '.join(p.strip() for p in text.split("|")) + "</speak>"
    done = subprocess.run(
        ["espeak-ng", "-m", "-v", voice, "-s", str(speed), "--stdout", ssml],
        capture_output=True,
        check=True,
        timeout=20,
    )
    wav = done.stdout
    rate = int.from_bytes(wav[24:28], "little")
    body = wav[44:]
    samples = np.frombuffer(body[: len(body) // 2 * 2], dtype="<i2").astype(np.int16)
    return resample(samples, rate, RATE)


def silent_runs(pcm: Int16Array, min_s: float) -> list[tuple[int, int]]:
    """(start, end) sample ranges where the audio stays under SILENT for at least min_s."""
    loud = np.abs(pcm.astype(np.int32)) >= SILENT
    edges = np.flatnonzero(np.diff(np.concatenate([[1], loud.astype(np.int8), [1]])))
    runs = list(zip(edges[::2], edges[1::2], strict=True))  # loud -> quiet, quiet -> loud
    return [(int(a), int(b)) for a, b in runs if b - a >= min_s * RATE]


def make_clip(text: str, voice: str, speed: int, pause_ms: list[int], rng: np.random.Generator) -> Clip:
    """The sentence with each break set to its exact length (or removed: the control)."""
    raw = speak(text, voice, speed)
    loud = np.flatnonzero(np.abs(raw.astype(np.int32)) >= SILENT)
    raw = raw[loud[0] : loud[-1] + 1]
    breaks = [r for r in silent_runs(raw, 0.45)]  # espeak's own gaps are shorter than its 700 ms breaks
    wanted = text.count("|")
    if len(breaks) != wanted:
        raise RuntimeError(f"{voice}/{speed} {text!r}: found {len(breaks)} breaks, expected {wanted}")
    pieces: list[Int16Array] = []
    pauses: list[tuple[float, float, int]] = []
    position, cursor = int(LEAD_S * RATE), 0
    for (start, end), ms in zip(breaks, pause_ms, strict=True):
        pieces.append(raw[cursor:start])
        position += start - cursor
        gap = ms * RATE // 1000
        if gap:
            pauses.append((position / RATE, (position + gap) / RATE, ms))
        pieces.append(np.zeros(gap, np.int16))
        position += gap
        cursor = end
    pieces.append(raw[cursor:])
    speech = np.concatenate(pieces)
    lead, tail = np.zeros(int(LEAD_S * RATE), np.int16), np.zeros(int(TAIL_S * RATE), np.int16)
    clean = np.concatenate([lead, speech, tail]).astype(np.float64)
    noisy = np.clip(clean + rng.normal(0.0, NOISE_STD, len(clean)), -32768, 32767).astype(np.int16)
    return Clip(
        f"{voice}/{speed}/{text.replace('|', '').replace('  ', ' ')}",
        noisy[: len(noisy) - len(noisy) % FRAME_SAMPLES],
        LEAD_S,
        LEAD_S + len(speech) / RATE,
        pauses,
    )


def corpus(quick: bool) -> tuple[list[Clip], list[Clip]]:
    rng = np.random.default_rng(34)
    voices, speeds = (VOICES[:2], SPEEDS[1:2]) if quick else (VOICES, SPEEDS)
    paused: list[Clip] = []
    control: list[Clip] = []
    turn = 0
    for voice in voices:
        for speed in speeds:
            for text in SENTENCES:
                count = text.count("|")
                lengths = [PAUSES_MS[(turn + i) % len(PAUSES_MS)] for i in range(count)]
                turn += count
                paused.append(make_clip(text, voice, speed, lengths, rng))
                control.append(make_clip(text, voice, speed, [0] * count, rng))
    return paused, control


class RecordingModel:
    """Silero, remembering each frame's probability so the rules can replay them."""

    def __init__(self) -> None:
        self._model = SileroModel()
        self.probabilities: list[float] = []

    def probability(self, window: npt.NDArray[np.float32]) -> float:
        p = self._model.probability(window)
        self.probabilities.append(p)
        return p

    def reset(self) -> None:
        self._model.reset()


def run_vad(clip: Clip) -> list[int]:
    """The real detector on the clip in 64 ms blocks; returns its utterance-end frame times (ns)."""
    model = RecordingModel()
    detector = VoiceDetector(VadConfig(), model)
    ends = []
    for offset in range(0, len(clip.pcm), BLOCK):
        stamp = offset * NS_PER_S // RATE
        for event in detector.process(clip.pcm[offset : offset + BLOCK], RATE, 1, stamp):
            if isinstance(event, VoiceActivity) and not event.active:
                ends.append(event.time_ns)
    clip.probabilities = model.probabilities
    return ends


def frames_of(clip: Clip) -> list[Frame]:
    return [
        Frame(clip.pcm[i : i + FRAME_SAMPLES], i * NS_PER_S // RATE)
        for i in range(0, len(clip.pcm), FRAME_SAMPLES)
    ]


def silence_rule(clip: Clip, frames: list[Frame], min_silence_ms: int) -> list[float]:
    """Turn ends (s): the arrival of each frame that closed an utterance."""
    segmenter = Segmenter(VadConfig(min_silence_duration_ms=min_silence_ms))
    decisions = []
    for frame, p in zip(frames, clip.probabilities, strict=True):
        for event in segmenter.push(frame, p):
            if isinstance(event, VoiceActivity) and not event.active:
                decisions.append((event.time_ns + FRAME_NS) / NS_PER_S)
    return decisions


class TimedModel:
    def __init__(self, model: SmartTurnModel) -> None:
        self._model = model
        self.last_s = 0.0
        self.times_ms: list[float] = []
        self.probabilities: list[float] = []
        self.verdicts: dict[str, list[bool]] = {"mid_sentence": [], "sentence_end": []}  # said finished?

    def completion_probability(self, audio: npt.NDArray[np.float32]) -> float:
        started = time.perf_counter()
        p = self._model.completion_probability(audio)
        self.last_s = time.perf_counter() - started
        self.times_ms.append(self.last_s * 1000)
        self.probabilities.append(p)
        return p


def smart_turn_rule(clip: Clip, frames: list[Frame], min_silence_ms: int, model: TimedModel) -> list[float]:
    segmenter = Segmenter(VadConfig(min_silence_duration_ms=min_silence_ms))
    wait = EndOfTurnConfig(model_path="set", incomplete_wait_ms=TOTAL_SILENCE_MS - min_silence_ms)
    turns = EndOfTurn(wait, model)
    decisions = []
    for frame, p in zip(frames, clip.probabilities, strict=True):
        arrival = frame.time_ns + FRAME_NS
        calls = len(model.probabilities)
        for _ in turns.push(segmenter.push(frame, p)):
            decisions.append(arrival / NS_PER_S + model.last_s)
        if len(model.probabilities) > calls:
            where = "mid_sentence" if arrival / NS_PER_S < clip.last_word_end else "sentence_end"
            model.verdicts[where].append(model.probabilities[-1] >= EndOfTurnConfig().threshold)
        if turns.tick(arrival) is not None:
            decisions.append(arrival / NS_PER_S)
    return decisions


@dataclass
class Outcome:
    cut: bool  # a turn end before the last word ended
    cut_pauses: set[int]  # nominal lengths of the pauses it was cut in
    latency_ms: float | None  # last word end -> first turn end after it


def judge(clip: Clip, decisions: list[float]) -> Outcome:
    early = [t for t in decisions if clip.speech_start < t < clip.last_word_end]
    cut_in = {ms for start, end, ms in clip.pauses if any(start < t <= end + 0.1 for t in early)}
    after = [t for t in decisions if t >= clip.last_word_end]
    latency = (after[0] - clip.last_word_end) * 1000 if after else None
    return Outcome(bool(early), cut_in, latency)


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def summarise(rule: str, paused: list[Outcome], control: list[Outcome], clips: list[Clip]) -> dict[str, Any]:
    pauses = [ms for clip in clips for _, _, ms in clip.pauses]
    cut_pauses = [ms for outcome in paused for ms in outcome.cut_pauses]
    latencies = [o.latency_ms for o in paused + control if o.latency_ms is not None]
    missed = sum(o.latency_ms is None for o in paused + control)
    return {
        "bench": "end_of_turn",
        "figure": rule,
        "false_cutoff_pct": round(100.0 * sum(o.cut for o in paused) / len(paused), 1),
        "pauses_cut_pct": round(100.0 * len(cut_pauses) / max(len(pauses), 1), 1),
        "cut_by_pause_ms": {
            str(ms): f"{cut_pauses.count(ms)}/{pauses.count(ms)}" for ms in sorted(set(pauses))
        },
        "control_cut_pct": round(100.0 * sum(o.cut for o in control) / len(control), 1),
        "p50": round(statistics.median(latencies), 0) if latencies else None,
        "p95": round(percentile(latencies, 95), 0),
        "unit": "ms latency",
        "no_turn_end": missed,
    }


def smart_turn_model(path: str | None) -> SmartTurnModel | None:
    try:
        return SmartTurnModel(path or bundled_model_path())
    except ModelNotFoundError as error:
        print(f"smart turn rules skipped: {error}")
        return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--smart-turn", help="Smart Turn v3 ONNX file (default: the pipecat-ai wheel's)")
    parser.add_argument("--quick", action="store_true", help="2 voices, 1 rate (a smoke run)")
    args = parser.parse_args()
    if shutil.which("espeak-ng") is None:
        print("espeak-ng is missing: run scripts/bootstrap.sh")
        return 1
    started = time.monotonic()
    paused, control = corpus(args.quick)
    clips = paused + control
    agree = 0
    for clip in clips:
        detector_ends = run_vad(clip)
        replay = silence_rule(clip, frames_of(clip), VadConfig().min_silence_duration_ms)
        agree += [round(t * NS_PER_S) - FRAME_NS for t in replay] == detector_ends
    if agree != len(clips):  # the replay must be what the node's detector does
        print(f"replay disagrees with VoiceDetector on {len(clips) - agree} of {len(clips)} clips")
        return 1
    rules: dict[str, Callable[[Clip, list[Frame]], list[float]]] = {
        f"silence_{ms}ms": partial(silence_rule, min_silence_ms=ms) for ms in SILENCE_RULES_MS
    }
    model = smart_turn_model(args.smart_turn)
    timed = TimedModel(model) if model else None
    if timed is not None:
        for ms in SMART_TURN_AT_MS:
            rules[f"smart_turn_at_{ms}ms"] = partial(smart_turn_rule, min_silence_ms=ms, model=timed)
    rows = []
    for rule, run in rules.items():
        outcomes = {id(clip): judge(clip, run(clip, frames_of(clip))) for clip in clips}
        row = summarise(rule, [outcomes[id(c)] for c in paused], [outcomes[id(c)] for c in control], paused)
        print(json.dumps(row))
        rows.append(row)
    if timed is not None and timed.times_ms:
        print(
            json.dumps(
                {
                    "bench": "end_of_turn",
                    "figure": "smart_turn_inference_ms",
                    "median": round(statistics.median(timed.times_ms), 1),
                    "p95": round(percentile(timed.times_ms, 95), 1),
                    "calls": len(timed.times_ms),
                    **{
                        f"said_finished_{where}": f"{sum(said)}/{len(said)}"
                        for where, said in timed.verdicts.items()
                    },
                }
            )
        )
    print()
    pause_count = sum(len(c.pauses) for c in paused)
    print(
        f"{len(paused)} sentences with {pause_count} pauses of {PAUSES_MS[0]}-{PAUSES_MS[-1]} ms "
        f"and {len(control)} without, {len(VOICES if not args.quick else VOICES[:2])} espeak-ng voices; "
        f"{time.monotonic() - started:.0f} s"
    )
    print(f"{'rule':<20} {'cut-off %':>9} {'pauses cut %':>12} {'control %':>9} {'p50 ms':>7} {'p95 ms':>7}")
    for row in rows:
        print(
            f"{row['figure']:<20} {row['false_cutoff_pct']:>9} {row['pauses_cut_pct']:>12} "
            f"{row['control_cut_pct']:>9} {row['p50']:>7} {row['p95']:>7}  {row['cut_by_pause_ms']}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
