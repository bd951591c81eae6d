"""Safety stop: detection, latency and false stops of the stop spotter (by_your_command.safety).

Everything is synthetic and offline: espeak-ng voices, a synthetic room (test/audio_io), the
spotter as the VAD node runs it (StopSpotter, one block at a time, mic and played reference
interleaved in time order). Scenarios:

  over_reply  the user says a stop phrase while the robot speaks (its echo -20 dBFS RMS at the mic,
              the user -26 dBFS: a robot near its mic is louder there than a user a metre away)
              gate: the raw mic, cancelled in the spotter (aec engine, audio_played)
              aec: as the node runs it in aec mode (vad.yaml: stop_input_topic audio): the raw mic
              beside audio_filtered, cancelled in the spotter as in gate mode (the same input)
              aec_filtered: the spotter on the mic after the echo_suppressor (what `audio_filtered`
              carries: stop_input_topic ''), the suppressor's controller kept across trials
              gate_raw (baseline): gate with the spotter's echo cancellation off (the raw mic)
  quiet       a stop in a quiet room (asleep / muted: the spotter is fed the same in every state)
  own_reply   the robot's own replies saying stop / stopping / halt, played into the mic: false stops
  chat        the user's chat with stop-like words ("don't stop believing"): false stops, in a quiet
              room and over a reply (gate, aec)
  lone_words  everyday words said alone in a quiet room ("robot", "what", "thanks"): false stops
  first_reply (--first-reply, on its own) a stop 1 or 2 s into the first reply after a start: a new
              spotter, one started from what an earlier one's canceller learned (stop_echo_memory)

Each mode is one robot listening for a while: the spotter (and in aec_filtered mode the
echo_suppressor's controller) is kept across trials on one timeline, so AEC3 and its echo guard
have converged on earlier replies, as on a robot that has been talking; each trial ends with 1.5 s of quiet.
Latency here = end of the word (as said, at the mic: not where the spotter's utterance ended, which
the robot's residual echo may carry on) -> the spotter's decision on a real-time stream: the audio the
decision waited for (the end silence, 32 ms blocks, the suppressor's reference wait) plus the
compute of the block that decided. The ROS hop after it (guard condition, publish) is not in it.
Voices: `TUNED` were looked at while choosing the parameters; `HELD_OUT` and `HELD_OUT_2` never
were (`HELD_OUT_2`'s quiet-room misses were read once, 2026-11-29; nothing was changed from them);
`HELD_OUT_3` (named espeak variants, used nowhere else) was added after that, for validation.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "by_your_command" / "test"))

from audio_io.synthetic_room import Room, at_level, trim_silence  # type: ignore[import-not-found]  # noqa: E402

from by_your_command.audio import echo_memory  # noqa: E402
from by_your_command.audio.echo import EchoConfig, EchoController  # noqa: E402
from by_your_command.audio.pcm import Int16Array, float_to_int16, read_wav, resample, to_mono  # noqa: E402
from by_your_command.local_speech.speaker import Speaker, SpeakerConfig  # noqa: E402
from by_your_command.safety.config import StopConfig  # noqa: E402
from by_your_command.safety.spotter import StopSpotter  # noqa: E402

RATE = 16000
BLOCK = 512
NS = 1_000_000_000
T0 = 1_700_000_000 * NS
TUNED = ["en-us", "en-gb", "en-us+f3", "en+m3", "en-gb-x-rp", "en-us+f2", "en-029", "en-gb-scotland"]
HELD_OUT = ["en-us-nyc", "en-gb-x-gbclan", "en+f4", "en-gb-x-gbcwmd", "en-us+m6"]
# A second held-out set (--more-voices), first run 2026-11-29: 94 of 100 over a reply with the
# spotter on the raw mic, 89 of 100 on audio_filtered.
HELD_OUT_2 = [
    "en-us+m1", "en-gb+f2", "en+m5", "en-us+f5", "en-gb-x-rp+m4",
    "en-029+f3", "en-us-nyc+m2", "en-gb-x-gbclan+f1", "en-gb-scotland+f4", "en-gb-x-gbcwmd+m2",
]  # fmt: skip
# A third (2026-11-29), after HELD_OUT_2's quiet misses had been read: espeak's named variants.
HELD_OUT_3 = [
    "en-us+Andy", "en-gb+belinda", "en+david", "en-us+linda", "en-gb-x-rp+edward",
    "en-029+max", "en-us-nyc+steph", "en-gb-x-gbclan+travis", "en-gb-scotland+anika", "en-gb-x-gbcwmd+quincy",
]  # fmt: skip
ROBOT_VOICES = ["en-gb", "en-us+m3", "en-us+f1", "en-gb-x-rp+f2"]
STOPS = ["stop", "stop it", "halt", "freeze", "stop stop"]
CHAT = [
    "don't stop believing",
    "the bus stop is over there",
    "where is my stopwatch",
    "I could not stop laughing",
    "we will stop by later",
    "stopping by the shop",
    "please don't stop the music",
    "the train will halt at the next station",
    "put it in the freezer",
    "a nonstop flight to Boston",
]
# Said alone, as people answer or call a robot: one word is where the spotter leans furthest to
# stopping (a lone word with a keyphrase hit stands for a clipped stop).
LONE_WORDS = [
    "yes", "no", "okay", "hello", "thanks", "left", "right", "go", "wait", "hey", "what",
    "robot", "look", "come", "help", "sure", "great", "hi", "up", "down", "again",
]  # fmt: skip
REPLY_TEMPLATES = [
    "Okay, I will stop here.",
    "Stopping.",
    "Stop. I heard you.",
    "I am stopping the arm now.",
    "The bus stop is two blocks away.",
    "Halt! Who goes there?",
    "I stopped at the door, as you asked.",
    "Let me stop and think about that for a moment.",
    "If you say stop, I stop moving.",
    "Halting all motion.",
    "I can stop, halt or freeze on command.",
    "The robot came to a halt near the table.",
    "Don't worry, I won't bump into it.",  # lone words that stand for a stop (HEARD_FOR_A_STOP)
    "No. I won't. Don't.",
]
OVER_REPLY = "Sure. I can see a red cup on the table next to a blue book and a small green plant."
ROOM = Room()
LEAD = int(0.5 * RATE)  # quiet before each trial's reply
ECHO_DBFS = -20.0  # the robot's voice at the mic, RMS while it speaks
USER_DBFS = -26.0  # the user a metre away: quieter there than the robot's own speaker
USER_ROOM = Room(delay_ms=5, gain=0.8, reverb_gain=0.2)


def speak(text: str, voice: str, wpm: int) -> Int16Array:
    binary = shutil.which("espeak-ng")
    if binary is None:
        raise SystemExit("espeak-ng is missing: run scripts/bootstrap.sh")
    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "s.wav"
        subprocess.run(
            [binary, "-v", voice, "-s", str(wpm), "-w", str(wav), text], check=True, capture_output=True
        )
        pcm, rate, channels = read_wav(wav)
    speech: Int16Array = trim_silence(resample(to_mono(pcm, channels), rate, RATE), RATE)
    return speech


def place(total: int, pcm: Int16Array, at: int) -> npt.NDArray[np.float64]:
    out = np.zeros(total)
    part = pcm[: max(0, total - at)].astype(np.float64)
    out[at : at + len(part)] = part
    return out


def _rms_db(x: npt.NDArray[np.float64]) -> float:
    return 10 * math.log10(float(np.mean(np.square(x / 32768.0))) + 1e-12)


@dataclass(frozen=True)
class Found:
    voice_start_ns: int
    voice_end_ns: int  # where the spotter's utterance ended (residual echo may carry it on)
    decided_ns: int  # the end of the block that decided, plus its compute


def compose(
    user: Int16Array | None, reply: Int16Array | None, user_at_s: float
) -> tuple[Int16Array, Int16Array, float]:
    """(mic, played, user's word end s): 0.5 s lead, the reply, the user at user_at_s, 1.5 s tail."""
    reply_s = len(reply) / RATE if reply is not None else 0.0
    user_s = user_at_s + len(user) / RATE if user is not None else 0.0
    total = int(RATE * (0.5 + max(reply_s, user_s) + 1.5))
    # Whole blocks: the next trial continues the timeline without a gap. (A dropped partial block
    # jumped the mic stamps by 2-30 ms; a jump under the echo controller's 20 ms tolerance shifted
    # the mic against the reference and the robot's voice passed uncancelled through the next reply.)
    total += -total % BLOCK
    played = np.zeros(total, dtype=np.int16)
    mic = np.random.default_rng(total).normal(0, 10, total)  # -70 dBFS room noise
    if reply is not None:
        played = float_to_int16(place(total, at_level(reply, -18.0), int(0.5 * RATE)) / 32768)
        echo = ROOM.echo(played, RATE).astype(np.float64)
        speaking = echo[int(0.5 * RATE) : int((0.5 + reply_s) * RATE)]
        mic += echo * 10 ** ((ECHO_DBFS - _rms_db(speaking)) / 20)
    if user is not None:
        near = USER_ROOM.echo(at_level(user, USER_DBFS), RATE)
        mic += place(total, near, int(user_at_s * RATE))
    return float_to_int16(mic / 32768), played, user_s + USER_ROOM.delay_ms / 1000


@functools.lru_cache(maxsize=1)
def robot_voice_sample() -> Int16Array:
    """What the VAD node primes its spotter with: its own "Stopping." (the robot's TTS voice)."""
    pcm, rate = Speaker(SpeakerConfig()).say(StopConfig().reply_text)
    return resample(np.frombuffer(pcm, dtype="<i2").astype(np.int16), rate, RATE)


class Stream:
    """One robot listening for a while, on one continuous timeline (see the docstring)."""

    def __init__(self, mode: str, config: StopConfig) -> None:
        self.mode = mode
        cancel = mode in ("gate", "aec")
        self.spotter = StopSpotter(config, cancel_echo=cancel, voice_sample=robot_voice_sample())
        filtered = mode == "aec_filtered"
        self.suppressor = EchoController(EchoConfig(mode="aec")) if filtered else None
        self.clock = T0
        self.cpu_s = 0.0  # the spotter's compute (not the echo_suppressor's)
        self.audio_s = 0.0

    def warm_up(self, reply: Int16Array) -> None:
        for _ in range(2):
            self.play(None, reply)

    def play(
        self, user: Int16Array | None, reply: Int16Array | None, user_at_s: float = 2.5
    ) -> tuple[list[Found], tuple[int, int]]:
        """Detections and the user's words at the mic (start ns, end ns)."""
        mic, played, end_s = compose(user, reply, user_at_s)
        base = self.clock
        found = []
        speaking = False
        for k in range(0, len(mic) - BLOCK + 1, BLOCK):
            stamp = base + k * NS // RATE
            reference = played[k : k + BLOCK]
            # The player publishes every block of a reply, its pauses too.
            playing = reply is not None and LEAD <= k < LEAD + len(reply)
            cpu = time.process_time()
            if playing:
                self.spotter.reference(reference, RATE, 1, stamp)
            self.cpu_s += time.process_time() - cpu
            began = time.perf_counter()
            blocks = [(mic[k : k + BLOCK], stamp)]
            if self.suppressor is not None:  # the echo_suppressor node, in front of the VAD
                if playing != speaking:
                    speaking = playing
                    self.suppressor.set_assistant_speaking(playing, stamp)
                if playing:
                    self.suppressor.add_reference(reference, RATE, 1, stamp)
                out = self.suppressor.process(mic[k : k + BLOCK], stamp, stamp)
                blocks = [(b.pcm, b.start_ns) for b in out]
            detections = []
            cpu = time.process_time()
            for pcm, start in blocks:
                detections += self.spotter.mic(pcm, RATE, 1, start)
            self.cpu_s += time.process_time() - cpu
            spent = time.perf_counter() - began
            block_end = stamp + BLOCK * NS // RATE
            decided = block_end + int(spent * NS)
            found += [Found(d.voice_start_ns, d.voice_end_ns, decided) for d in detections]
        self.audio_s += len(mic) / RATE
        self.clock = base + len(mic) * NS // RATE  # continuous: the trial ends with 1.5 s of quiet
        said_ns = (len(user) if user is not None else 0) * NS // RATE
        return found, (base + int(end_s * NS) - said_ns, base + int(end_s * NS))


def pct(a: int, b: int) -> str:
    return f"{100 * a / max(b, 1):5.1f} % ({a}/{b})"


def p95(xs: list[float]) -> str:
    if not xs:
        return "n/a"
    return f"median {np.median(xs) * 1000:.0f} ms, p95 {np.percentile(xs, 95) * 1000:.0f} ms"


def ms(xs: list[float]) -> dict[str, float]:
    """p50 / p95 in ms of times in seconds, for the JSON figures (empty: none)."""
    if not xs:
        return {}
    return {"p50": round(float(np.median(xs)) * 1e3, 1), "p95": round(float(np.percentile(xs, 95)) * 1e3, 1)}


def emit(figure: str, **fields: object) -> None:
    """One figure as a JSON line (make bench collects them into its summary)."""
    print(json.dumps({"bench": "safety_stop", "figure": figure, **fields}), flush=True)


def node_path(trials: int) -> list[float]:
    """End of the word -> `stop` on response_cmd through the real silero_vad_node (a process, gate
    mode), the audio published in real time and stamped with the wall clock like audio_capture."""
    import os
    import threading
    import uuid

    import rclpy
    from builtin_interfaces.msg import Time
    from by_your_command_msgs.msg import AudioChunk
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import String

    from by_your_command.nodes._audio_msgs import make_audio_chunk
    from by_your_command.nodes._qos import RELIABLE, STREAM

    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    namespace = f"/bench_{uuid.uuid4().hex[:8]}"
    args = [
        sys.executable,
        "-m",
        "by_your_command.nodes.silero_vad_node",
        "--ros-args",
        "-r",
        f"__ns:={namespace}",
    ]
    args += ["-p", "input_topic:=audio", "-p", "echo_gate:=true"]
    vad = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = Node("bench_safety_stop", namespace=namespace, context=context)
    mic = node.create_publisher(AudioChunk, "audio", STREAM)
    arrivals: list[int] = []
    lock = threading.Lock()

    def on_command(msg: String) -> None:
        if msg.data == "stop":
            with lock:
                arrivals.append(time.time_ns())

    node.create_subscription(String, "response_cmd", on_command, RELIABLE)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    threading.Thread(target=executor.spin, daemon=True).start()
    latencies = []
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (
            mic.get_subscription_count() and node.count_publishers(f"{namespace}/response_cmd")
        ):
            time.sleep(0.05)  # discovery, polled
        quiet = np.zeros(int(1.2 * RATE), dtype=np.int16)
        for index in range(trials):
            phrase = STOPS[index % len(STOPS)]
            user = USER_ROOM.echo(at_level(speak(phrase, TUNED[index % len(TUNED)], 165), USER_DBFS), RATE)
            audio = np.concatenate([quiet, user, quiet])
            noise = np.random.default_rng(index).normal(0, 10, len(audio))
            audio = float_to_int16((audio + noise) / 32768)
            start_ns = time.time_ns()
            word_end = start_ns + (len(quiet) + len(user)) * NS // RATE
            with lock:
                seen = len(arrivals)
            for k in range(0, len(audio) - BLOCK + 1, BLOCK):
                due = start_ns + (k + BLOCK) * NS // RATE  # a block goes out when its last sample is in
                time.sleep(max(0.0, (due - time.time_ns()) / NS))  # real-time pacing of the capture
                stamp = start_ns + k * NS // RATE
                mic.publish(
                    make_audio_chunk(audio[k : k + BLOCK], RATE, 1, Time(sec=stamp // NS, nanosec=stamp % NS))
                )
            time.sleep(1.0)  # the refractory window between trials
            with lock:
                if len(arrivals) > seen:
                    latencies.append((arrivals[seen] - word_end) / NS)
    finally:
        vad.terminate()
        try:
            vad.wait(5)
        except subprocess.TimeoutExpired:
            vad.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return latencies


def stops_heard(
    stream: Stream, texts: list[str], voices: list[str], over_reply: bool = False
) -> dict[str, int]:
    """Each text said in each voice, in a quiet room or over a reply: how many voices' saying it
    stopped the robot."""
    stopped: dict[str, int] = {}
    for v_index, voice in enumerate(voices):
        for t_index, text in enumerate(texts):
            reply = None
            if over_reply:
                reply = speak(OVER_REPLY, ROBOT_VOICES[(v_index + t_index) % len(ROBOT_VOICES)], 170)
            found, _ = stream.play(speak(text, voice, 165), reply, 1.5 if over_reply else 0.5)
            if found:
                stopped[text] = stopped.get(text, 0) + 1
    return stopped


def first_reply(config: StopConfig) -> None:
    """A stop 1 or 2 s into the first reply after the spotter starts (gate mode, held-out voices):
    a new spotter, one whose canceller starts from what an earlier one learned of the room (the
    node keeps it: stop_echo_memory; learned here over four other replies, kept and restored
    through the file), and, as the baseline, one that has been listening (the scenarios above)."""
    earlier = Stream("gate", config)
    for index in range(4):
        earlier.play(None, speak(REPLY_TEMPLATES[index], ROBOT_VOICES[index], 170))
    listening = speak(REPLY_TEMPLATES[7] + " " + OVER_REPLY, ROBOT_VOICES[0], 170)
    with tempfile.TemporaryDirectory() as tmp:
        kept = Path(tmp) / "stop_spotter.npz"
        assert earlier.spotter.echo_controller is not None
        assert echo_memory.keep(earlier.spotter.echo_controller, kept) is not None
        for at in (1.0, 2.0):
            heard = {"new": 0, "remembered": 0, "listening": 0}
            total = 0
            for v_index, voice in enumerate(HELD_OUT):
                for p_index, phrase in enumerate(STOPS):
                    reply = speak(OVER_REPLY, ROBOT_VOICES[(v_index + p_index) % len(ROBOT_VOICES)], 170)
                    total += 1
                    for start in heard:
                        stream = Stream("gate", config)
                        if start == "remembered":
                            assert stream.spotter.echo_controller is not None
                            restored = echo_memory.restore(stream.spotter.echo_controller, kept)
                            assert "starting from" in restored.message, restored.message
                        elif start == "listening":
                            stream.warm_up(listening)
                        found, (word_start, word_end) = stream.play(speak(phrase, voice, 170), reply, at)
                        heard[start] += any(
                            f.voice_start_ns < word_end and f.voice_end_ns > word_start for f in found
                        )
            print(
                f"first reply after a start, stop {at:.0f} s in (held-out): "
                + ", ".join(f"{start} {pct(count, total)}" for start, count in heard.items()),
                flush=True,
            )
            emit("first_reply_detected", at_s=at, total=total, **heard)


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--replies", type=int, default=200, help="own replies played into the mic")
    parser.add_argument("--quick", action="store_true", help="fewer voices and replies (a smoke run)")
    parser.add_argument(
        "--modes", default="gate,aec,aec_filtered,gate_raw,quiet", help="detection scenarios to run"
    )
    parser.add_argument("--node-trials", type=int, default=20, help="stops through the real node (0: none)")
    parser.add_argument(
        "--more-voices", action="store_true", help="detection on the second and third held-out sets too"
    )
    parser.add_argument("--sets", default="", help="only these voice sets (e.g. held_out_3)")
    parser.add_argument(
        "--first-reply",
        action="store_true",
        help="only: stops early in the first reply after a start, new spotter vs remembered canceller",
    )
    args = parser.parse_args()
    config = StopConfig()
    if args.first_reply:
        first_reply(config)
        return 0
    rates = [150, 185]
    sets = {"tuned": TUNED, "held_out": HELD_OUT}
    if args.quick:
        sets = {"tuned": TUNED[:2], "held_out": HELD_OUT[:2]}
        args.replies = min(args.replies, 24)
    if args.more_voices:
        sets |= {"held_out_2": HELD_OUT_2, "held_out_3": HELD_OUT_3}
    if args.sets:
        every = {"tuned": TUNED, "held_out": HELD_OUT, "held_out_2": HELD_OUT_2, "held_out_3": HELD_OUT_3}
        sets = {name: every[name] for name in args.sets.split(",")}
    began = time.perf_counter()

    probe = StopSpotter(config, cancel_echo=False)._mic_recognizer
    decode_times = []
    for phrase in STOPS:
        pcm = speak(phrase, "en-us", 160)
        t = time.perf_counter()
        probe.start()
        probe.feed(pcm)
        probe.finish()
        decode_times.append(time.perf_counter() - t)
    print(f"baseline: decoding a whole stop phrase after it ended (not streamed): {p95(decode_times)}")

    if args.node_trials:
        node = node_path(args.node_trials)
        print(
            f"node path (silero_vad_node process, gate mode, quiet room): end of word -> `stop` on "
            f"response_cmd: {p95(node)}, {len(node)}/{args.node_trials} heard",
            flush=True,
        )
        emit("node_word_end_to_stop_routed_ms", **ms(node), heard=len(node), trials=args.node_trials)

    warm = speak(REPLY_TEMPLATES[7] + " " + OVER_REPLY, ROBOT_VOICES[0], 170)
    for set_name, voices in sets.items():
        for mode in [m for m in args.modes.split(",") if m]:
            stream = Stream(mode, config)
            if mode != "quiet":
                stream.warm_up(warm)
            hits = total = 0
            latencies: list[float] = []
            for v_index, voice in enumerate(voices):
                for rate in rates:
                    for p_index, phrase in enumerate(STOPS):
                        robot = ROBOT_VOICES[(v_index + p_index) % len(ROBOT_VOICES)]
                        reply = None if mode == "quiet" else speak(OVER_REPLY, robot, 170)
                        at = 1.5 + (p_index + rate) % 3  # 1.5, 2.5 or 3.5 s into a ~5 s reply
                        found, (word_start, word_end) = stream.play(speak(phrase, voice, rate), reply, at)
                        # A stop heard in the user's words, however late the utterance ended.
                        good = [
                            f for f in found if f.voice_start_ns < word_end and f.voice_end_ns > word_start
                        ]
                        total += 1
                        if good:
                            hits += 1
                            latencies.append((good[0].decided_ns - word_end) / NS)
            spotter = stream.spotter
            print(
                f"{set_name:8s} {mode:12s} detected {pct(hits, total)}, end of word -> decision: "
                f"{p95(latencies)} (own_voice rejections {spotter.own_voice}, repeated {spotter.repeated}; "
                f"spotter CPU {100 * stream.cpu_s / stream.audio_s:.1f} % of a core)",
                flush=True,
            )
            emit(
                "detected",
                voices=set_name,
                mode=mode,
                value=round(hits / max(total, 1), 3),
                unit="share",
                hits=hits,
                total=total,
                word_end_to_decision_ms=ms(latencies),
            )

    # aec mode's spotter hears what it hears in gate mode (the raw mic): not played twice.
    streams = {mode: Stream(mode, config) for mode in ("gate", "aec_filtered")}
    for stream in streams.values():
        stream.warm_up(warm)
    false_stops = dict.fromkeys(streams, 0)
    for index in range(args.replies):
        template = REPLY_TEMPLATES[index % len(REPLY_TEMPLATES)]
        voice = ROBOT_VOICES[(index // len(REPLY_TEMPLATES)) % len(ROBOT_VOICES)]
        reply = speak(template, voice, [150, 170, 190][index % 3])
        for mode, stream in streams.items():
            found, _ = stream.play(None, reply)
            false_stops[mode] += len(found)
    for mode, count in false_stops.items():
        spotter = streams[mode].spotter
        label = "gate, aec" if mode == "gate" else mode
        print(
            f"own replies {label:12s}: false stops {pct(count, args.replies)} "
            f"(rejected as own voice {spotter.own_voice}, repeated {spotter.repeated})",
            flush=True,
        )
        emit("own_reply_false_stops", mode=label, value=count, unit="stops", replies=args.replies, goal=0)

    quiet, over_reply = Stream("quiet", config), Stream("gate", config)
    over_reply.warm_up(warm)
    voices = TUNED + HELD_OUT
    for name, texts, label, stream in (
        ("chat_false_stops", CHAT, "chat with stop-like words", quiet),
        ("chat_over_reply_false_stops", CHAT, "the same chat over a reply (gate, aec)", over_reply),
        ("lone_word_false_stops", LONE_WORDS, "everyday words said alone", quiet),
    ):
        stopped = stops_heard(stream, texts, voices, over_reply=stream is over_reply)
        count, total = sum(stopped.values()), len(texts) * len(voices)
        print(f"{label}: false stops {pct(count, total)} {stopped}")
        emit(name, value=round(count / total, 3), unit="share", lines=total, stopped=stopped)
    print(f"bench time {time.perf_counter() - began:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
