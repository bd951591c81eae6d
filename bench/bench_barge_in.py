"""Barge-in through the real path (issue 34): does the robot keep talking through coughs, knocks
and "uh-huh", stop at once for a real interruption, and remember exactly what was heard?

A microphone thread here publishes `audio` in real time (512-sample blocks, a faint room); the
real silero_vad_node (shipped pre-roll) → ros_ai_bridge → `byc agent` (OpenAI emulator on a thread
here; full duplex, its local pocketsphinx transcriber, min_barge_in_words 2) → simple_audio_player
(real-time WAV sink, 20 ms blocks). Each trial: a typed question, a story playing; after 600 ms of
it a false sound goes into the mic (a noise burst or a cough of 50–300 ms, or a backchannel
"uh-huh", "yeah", "okay", "mm-hm" in one of the espeak-ng voices), then, once the story plays on, a
real interruption (2–6 words in the same voices). Goals measured:
1. false sounds: confirmed interruptions (goal 0), how many paused the reply at all (Silero may
   not fire on a knock) and resumed, and audio lost at the resume (goal <= one 20 ms block: the
   player's WAV is aligned with the reply's audio, sample by sample);
2. real interruptions confirmed (goal >= 95 %);
3. speech onset (the VAD's voice_activity True, heard here) → the player's first paused status for
   that reply (goal p95 <= 60 ms), and the sound's first sample in the mic → paused;
4. truncation after a false interruption: the emulator's conversation.item.truncate audio_end_ms
   vs the player's frozen played_ms of the cut reply, and the WAV holds that much of the reply
   (goal +- one block).
Voices en-us, en-gb and en-us+f3 are the ones the defaults were looked at with; en+m3 and
en-us+m7 are held out and reported apart.

Modes: `external` (the mic hears only the user; the VAD reads `audio`), and `aec`: the mic also
hears the robot (the player's audio_played, 10 ms late, through a short synthetic room) and the
echo_suppressor (mode aec) feeds the VAD on `audio_filtered`; onsets while the user is silent are
counted there as echo onsets.

Same-run floors: a raw DDS publish→subscribe and a raw WebSocket round trip (the onset → paused
path is 4 DDS hops: VAD→bridge, bridge→player, player→bench, VAD→bench only subtracts, and one
WebSocket round trip bridge→agent→bridge).

    scripts/run.sh python bench/bench_barge_in.py [--trials N] [--quick] [--mode external|aec|all]
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
import wave
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _agent_bench import (  # noqa: E402
    CHUNK_MS,
    AgentGraph,
    EmulatorThread,
    ExtraNode,
    Stamped,
    agent_graph,
    dds_one_way_ms,
    percentile,
    summary,
    table,
    wait_until,
    websocket_round_trip_ms,
)

from by_your_command.audio.pcm import resample  # noqa: E402
from by_your_command.emulators.openai_script import Say, Script, Turn  # noqa: E402
from by_your_command.emulators.synthetic_speech import OUTPUT_RATE, speech_pcm  # noqa: E402
from by_your_command.local_speech.speaker import Speaker, SpeakerConfig  # noqa: E402

GOAL_PAUSE_P95_MS = 60.0
GOAL_REAL_CONFIRMED = 0.95
BLOCK_MS = 20  # the player's default block: the goal for lost audio and the truncation error
MIC_RATE = 16000
MIC_BLOCK = 512  # 32 ms, as the audio_capturer publishes
NS_PER_S = 1_000_000_000
MS_PER_CHAR = 40
STORY = "Once upon a time a robot told a long story about all the things it saw in the kitchen today. " * 2
ANSWER = "Yes?"
PLAYED_BEFORE_FALSE_MS = 600
PLAYED_BETWEEN_MS = 400  # the story plays on this much after a resume before the real interruption
NO_ONSET_WAIT_S = 0.8  # after a sound that made no onset: the VAD would have fired by then
SOUND_START_LEVEL = 500  # |sample| above this: the sound has started (the room is ~30)

VOICES_TUNED = ("en-us", "en-gb", "en-us+f3")
VOICES_HELD_OUT = ("en+m3", "en-us+m7")
VOICES = VOICES_TUNED + VOICES_HELD_OUT
# (what it is, what espeak-ng is given): espeak spells "mm-hm" out as letters ("em em aitch em"),
# "hmm hmm" is its nearest hum
BACKCHANNELS = (("uh-huh", "uh-huh"), ("yeah", "yeah"), ("okay", "okay"), ("mm-hm", "hmm hmm"))
QUESTIONS = (  # 2-6 words; no "stop" (the VAD's safety stop has its own path)
    "wait a moment",
    "what time is it",
    "turn to the left now",
    "can you hear me",
    "tell me about the weather today",
    "hold on robot",
    "look at the door please",
    "where are my keys",
)
FALSE_KINDS = ("noise", "cough", "backchannel", "backchannel")

AEC_DELAY_MS = 10.0
AEC_GAIN = 0.5


# --- sounds ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Sound:
    kind: str  # noise, cough, backchannel, question
    label: str  # what it is: "noise 120 ms", "yeah"
    voice: str  # "" for noise and synthetic coughs
    pcm: np.ndarray  # int16 at MIC_RATE

    @property
    def held_out(self) -> bool:
        return self.voice in VOICES_HELD_OUT


def spoken(text: str, voice: str) -> np.ndarray:
    pcm, rate = Speaker(SpeakerConfig(voice=voice, sample_rate=MIC_RATE)).say(text)
    samples = np.frombuffer(pcm, dtype="<i2").astype(np.float64)
    voiced = np.flatnonzero(np.abs(samples) > 100)
    samples = samples[voiced[0] : voiced[-1] + 1] if len(voiced) else samples
    return (samples * 10000 / max(1.0, float(np.max(np.abs(samples))))).astype(np.int16)  # peak -10 dBFS


def noise_burst(ms: int, rng: np.random.Generator) -> np.ndarray:
    """A knock or a clatter: broadband noise, a fast attack and decay."""
    n = ms * MIC_RATE // 1000
    envelope = np.exp(-np.arange(n) / (n / 3)) * np.minimum(1.0, np.arange(n) / (MIC_RATE * 0.002))
    level = rng.uniform(4000, 12000)
    return (level * envelope * np.clip(rng.standard_normal(n), -3, 3) / 3).astype(np.int16)


def cough(ms: int, rng: np.random.Generator) -> np.ndarray:
    """A cough: a burst of low-passed breath noise with a short voiced onset (a glottal buzz)."""
    n = ms * MIC_RATE // 1000
    t = np.arange(n) / MIC_RATE
    breath = np.convolve(rng.standard_normal(n + 8), np.ones(8) / 8, mode="valid")[:n]
    pitch = rng.uniform(120, 220)
    buzz = np.sign(np.sin(2 * np.pi * pitch * t)) * np.exp(-t / 0.04)
    envelope = np.exp(-t / (ms / 1000 / 3)) * np.minimum(1.0, t / 0.005)
    pcm = envelope * (0.7 * breath / (np.std(breath) + 1e-9) + 0.6 * buzz)
    out: np.ndarray = (pcm * rng.uniform(3000, 9000) / 2).astype(np.int16)
    return out


def false_sounds(trials: int, seed: int) -> list[Sound]:
    rng = np.random.default_rng(seed)
    sounds: list[Sound] = []
    for trial in range(trials):
        kind = FALSE_KINDS[trial % len(FALSE_KINDS)]
        voice = VOICES[trial % len(VOICES)]
        if kind == "noise":
            ms = int(rng.integers(50, 301))
            sounds.append(Sound(kind, f"noise {ms} ms", "", noise_burst(ms, rng)))
        elif kind == "cough":
            ms = int(rng.integers(50, 301))
            sounds.append(Sound(kind, f"cough {ms} ms", "", cough(ms, rng)))
        else:
            label, text = BACKCHANNELS[(trial // len(FALSE_KINDS)) % len(BACKCHANNELS)]
            sounds.append(Sound(kind, label, voice, spoken(text, voice)))
    return sounds


def real_sounds(trials: int) -> list[Sound]:
    return [
        Sound("question", text, voice, spoken(text, voice))
        for trial in range(trials)
        for text, voice in [(QUESTIONS[trial % len(QUESTIONS)], VOICES[(trial + 2) % len(VOICES)])]
    ]


def sound_start(pcm: np.ndarray) -> int:
    loud = np.flatnonzero(np.abs(pcm.astype(np.int32)) > SOUND_START_LEVEL)
    return int(loud[0]) if len(loud) else 0


# --- the microphone ----------------------------------------------------------------------------


class Microphone:
    """A live microphone on `audio`: a faint room, real time, 512-sample blocks published when
    captured (at their end), stamped at their start on one timeline. `say` mixes a sound in from
    the next block; in aec mode the robot's own voice (the player's audio_played, `delay_ms` late,
    through a short room) is mixed in by its stamps."""

    RING_S = 10

    def __init__(self, publisher: Any, played: list[Stamped] | None) -> None:
        self._publisher = publisher
        self._played = played
        self._pending: list[np.ndarray] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self.sounds_at: list[tuple[float, float]] = []  # (first sample, last sample) on time.monotonic()
        self.error: BaseException | None = None
        self.late_reference_samples = 0
        self._ring = np.zeros(self.RING_S * MIC_RATE)
        self._ir = self._room()
        self._played_seen = 0
        self._start_wall = self._start_mono = 0.0
        self._start_wall_ns = 0
        self._sent = 0

    @staticmethod
    def _room() -> np.ndarray:
        rng = np.random.default_rng(3)
        tail = int(0.04 * MIC_RATE)
        ir = (
            0.12
            * rng.standard_normal(tail)
            * np.exp(-np.arange(tail) / (0.012 * MIC_RATE))
            / np.sqrt(tail / 8)
        )
        ir[0] = 1.0
        scaled: np.ndarray = AEC_GAIN * ir
        return scaled

    def say(self, pcm: np.ndarray) -> None:
        with self._lock:
            self._pending.append(pcm.astype(np.int16))

    def busy(self) -> bool:
        with self._lock:
            return bool(self._pending) or self._queued

    def _mix_reference(self) -> None:
        """Add the robot's new played blocks to the ring at their place on the mic's timeline."""
        assert self._played is not None
        from by_your_command.nodes._audio_msgs import pcm_of

        new = self._played[self._played_seen :]
        self._played_seen += len(new)
        for stamped in new:
            msg = stamped.msg
            stamp_ns = int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec)
            pcm = resample(pcm_of(msg), int(msg.sample_rate), MIC_RATE).astype(np.float64)
            echo = np.convolve(pcm, self._ir)
            at = (stamp_ns + int(AEC_DELAY_MS * 1e6) - self._start_wall_ns) * MIC_RATE // NS_PER_S
            late = max(0, self._sent - at)
            self.late_reference_samples += min(late, len(echo))
            for offset in range(late, len(echo)):  # a ring: indices wrap
                self._ring[(at + offset) % len(self._ring)] += echo[offset]

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as error:  # seen by the trials (check), never a silent death
            self.error = error

    def _loop(self) -> None:
        from builtin_interfaces.msg import Time

        from by_your_command.nodes._audio_msgs import make_audio_chunk

        rng = np.random.default_rng(5)
        self._start_wall_ns, self._start_mono = time.time_ns(), time.monotonic()
        queued = np.zeros(0, dtype=np.int16)
        self._queued = False
        while not self._stop.is_set():
            # a real device hands a block over once it is captured
            self._stop.wait(
                max(0.0, self._start_mono + (self._sent + MIC_BLOCK) / MIC_RATE - time.monotonic())
            )
            block = rng.normal(0, 30, MIC_BLOCK)
            if self._played is not None:
                self._mix_reference()
                where = np.arange(self._sent, self._sent + MIC_BLOCK) % len(self._ring)
                block += self._ring[where]
                self._ring[where] = 0.0
            with self._lock:
                if self._pending and not len(queued):
                    queued = self._pending.pop(0)
                    first = self._start_mono + (self._sent + sound_start(queued)) / MIC_RATE
                    self.sounds_at.append((first, self._start_mono + (self._sent + len(queued)) / MIC_RATE))
                part, queued = queued[:MIC_BLOCK], queued[MIC_BLOCK:]
                self._queued = bool(len(queued))
            block[: len(part)] += part
            stamp = self._start_wall_ns + self._sent * NS_PER_S // MIC_RATE
            pcm = np.clip(block, -32768, 32767).astype(np.int16)
            self._publisher.publish(
                make_audio_chunk(pcm, MIC_RATE, 1, Time(sec=stamp // NS_PER_S, nanosec=stamp % NS_PER_S))
            )
            self._sent += MIC_BLOCK

    def __enter__(self) -> Microphone:
        self._queued = False
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


# --- one mode's trials -------------------------------------------------------------------------


@dataclass
class Heard:
    """What one sound over the reply did."""

    sound: Sound
    onset: bool = False  # the VAD fired
    paused: bool = False  # the player paused the reply
    outcome: str = ""  # "resumed", "cut", or "" (no pause)
    onset_to_paused_ms: float | None = None
    sound_to_paused_ms: float | None = None
    played_ms_at_pause: int | None = None


@dataclass
class Trial:
    false: Heard
    real: Heard | None  # None when the false sound was confirmed (the story was cut by it)
    story_played_ms: int = 0  # of the story, as the player reports it at its end (frozen when cut)
    story_cut: bool = False
    truncate_ms: int | None = None  # the emulator's audio_end_ms of that cut


@dataclass
class ModeResult:
    mode: str
    trials: list[Trial] = field(default_factory=list)
    echo_onsets: int = 0  # onsets with no user sound in the mic (aec: the robot heard itself)
    echo_pauses: int = 0  # ...that paused the reply
    late_reference_samples: int = 0
    lost_ms: list[float] = field(default_factory=list)  # per story: audio missing in the WAV
    wav_vs_played_ms: list[float] = field(default_factory=list)  # cut stories: WAV length - played_ms
    wav_problems: list[str] = field(default_factory=list)


class Runner:
    def __init__(self, graph: AgentGraph, mic: Microphone) -> None:
        self.graph, self.bench, self.mic = graph, graph.bench, mic
        assert isinstance(graph.emulator, EmulatorThread)
        self.emulator = graph.emulator
        self.known: set[str] = set()

    def check(self) -> None:
        self.graph.check()
        if self.mic.error is not None:
            raise RuntimeError(f"the microphone thread died: {self.mic.error!r}")

    def until(self, condition: Callable[[], Any], timeout: float, what: str) -> Any:
        def checked() -> Any:
            self.check()
            return condition()

        return wait_until(checked, timeout, what)

    def statuses(self, stream: str, after: float = 0.0) -> list[Stamped]:
        return [s for s in self.bench.statuses_of(stream) if s.at >= after]

    def played_ms(self, stream: str) -> int:
        return max((s.msg.played_ms for s in self.bench.statuses_of(stream)), default=0)

    def start_reply(self, text: str, played_ms: int) -> str:
        self.bench.type_text(text)
        status = self.until(
            lambda: (s := self.bench.new_stream(self.known)) and s, 30, f"a reply to {text!r} playing"
        )
        stream: str = status.msg.stream_id
        self.known.add(stream)
        self.until(lambda: self.played_ms(stream) >= played_ms, 30, f"{played_ms} ms of it played")
        return stream

    def finished(self, stream: str) -> Stamped:
        end: Stamped = self.until(
            lambda: next((s for s in self.statuses(stream) if s.msg.finished or s.msg.interrupted), None),
            60,
            f"{stream} finished",
        )
        return end

    def answer(self) -> None:
        """The next reply (the answer to what cut the story) plays to its end."""
        status = self.until(lambda: self.bench.new_stream(self.known), 30, "the answer playing")
        self.known.add(status.msg.stream_id)
        self.finished(status.msg.stream_id)

    def over(self, sound: Sound, stream: str) -> Heard:
        """Play `sound` into the mic over `stream` and wait for what it did."""
        heard = Heard(sound)
        activity_from = len(self.bench.activity_heard)
        interruptions_from = len(self.bench.interruptions)
        said_from = len(self.mic.sounds_at)
        self.mic.say(sound.pcm)
        first, last = self.until(
            lambda: self.mic.sounds_at[said_from] if len(self.mic.sounds_at) > said_from else None,
            10,
            "the sound in the mic",
        )

        def onset() -> Stamped | None:
            heard = self.bench.activity_heard
            new = next((a for a in heard[activity_from:] if a.msg.data), None)
            if new is None and activity_from and heard[activity_from - 1].msg.data:
                return heard[activity_from - 1]  # the VAD was in an (echo) utterance when the sound began
            return new

        def resolution() -> Stamped | None:
            return next(
                (
                    i
                    for i in self.bench.interruptions[interruptions_from:]
                    if i.msg.stream_id == stream and i.msg.action in (0, 2)  # CUT, RESUME
                ),
                None,
            )

        while time.monotonic() < last + NO_ONSET_WAIT_S and onset() is None:
            self.check()
            time.sleep(0.005)
        started = onset()
        if started is None:
            return heard
        heard.onset = True
        paused = [s for s in self.statuses(stream, started.at - 0.5) if s.msg.paused]
        if not paused:  # the pause may still be on its way
            try:
                self.until(
                    lambda: [s for s in self.statuses(stream, started.at - 0.5) if s.msg.paused], 2, "paused"
                )
            except TimeoutError:
                pass
        paused = [s for s in self.statuses(stream, started.at - 0.5) if s.msg.paused]
        if paused:
            heard.paused = True
            heard.onset_to_paused_ms = 1000 * (paused[0].at - started.at)
            heard.sound_to_paused_ms = 1000 * (paused[0].at - first)
            heard.played_ms_at_pause = int(paused[0].msg.played_ms)
        done = self.until(resolution, 15, f"the barge-in by {sound.label!r} judged")
        heard.outcome = "cut" if done.msg.action == 0 else "resumed"
        return heard

    def trial(self, false: Sound, real: Sound) -> Trial:
        truncates_from = len(self.emulator.events("conversation.item.truncate"))
        stream = self.start_reply("tell me a story", PLAYED_BEFORE_FALSE_MS)
        first = self.over(false, stream)
        trial = Trial(first, None)
        if first.outcome != "cut":
            resumed_at = self.played_ms(stream)
            self.until(
                lambda: (
                    self.played_ms(stream) >= resumed_at + PLAYED_BETWEEN_MS
                    or any(s.msg.finished for s in self.statuses(stream))
                ),
                30,
                "the story playing on",
            )
            trial.real = self.over(real, stream)
        end = self.finished(stream)
        trial.story_cut = bool(end.msg.interrupted)
        trial.story_played_ms = int(end.msg.played_ms)
        if trial.story_cut:
            truncates = self.until(
                lambda: self.emulator.events("conversation.item.truncate")[truncates_from:],
                10,
                "the truncation",
            )
            trial.truncate_ms = int(truncates[0]["audio_end_ms"])
        else:  # nothing cut the story: its answer turn is still due, spent on a typed line
            self.bench.type_text("go on")
        self.answer()
        return trial


def graph_nodes(mode: str) -> tuple[ExtraNode, ...]:
    vad_input = "audio_filtered" if mode == "aec" else "audio"
    vad = ExtraNode(
        "silero_vad_node",
        (f"input_topic:={vad_input}", "echo_gate:=false", "stop_spotter:=false"),
        r"VAD ready on",
    )
    if mode == "aec":  # each run starts its canceller new, as before the echo path was remembered
        suppressor = ExtraNode(
            "echo_suppressor", ("mode:=aec", "aec_echo_memory:=none"), r"echo control ready"
        )
        return (suppressor, vad)
    return (vad,)


def measure(mode: str, trials: int, seed: int) -> ModeResult:
    from by_your_command_msgs.msg import AudioChunk

    from by_your_command.nodes._qos import AUDIO_IN

    falses, reals = false_sounds(trials, seed), real_sounds(trials)
    script = Script(
        turns=(Turn(Say(STORY)), Turn(Say(ANSWER))) * (trials + 1), pace=0.0, ms_per_char=MS_PER_CHAR
    )
    settings: dict[str, Any] = {"echo_mode": mode}
    result = ModeResult(mode)
    with agent_graph(script, f"barge_in_{mode}", "openai", nodes=graph_nodes(mode), **settings) as graph:
        bench = graph.bench
        mic_out = bench.node.create_publisher(AudioChunk, "audio", AUDIO_IN)
        wait_until(lambda: mic_out.get_subscription_count() > 0, 30, "a listener on audio")
        with Microphone(mic_out, bench.played if mode == "aec" else None) as mic:
            runner = Runner(graph, mic)
            runner.trial(false_sounds(1, seed + 1)[0], real_sounds(1)[0])  # warm-up: not counted
            for index, (false, real) in enumerate(zip(falses, reals, strict=True)):
                trial = runner.trial(false, real)
                result.trials.append(trial)
                real_text = (
                    "-"
                    if trial.real is None
                    else f"{trial.real.sound.label!r} ({trial.real.sound.voice}) {trial.real.outcome}"
                )
                print(
                    f"{mode} trial {index}: {false.label!r} ({false.voice or '-'}) "
                    f"onset={trial.false.onset} {trial.false.outcome or 'no pause'}; real {real_text}",
                    flush=True,
                )
            sounds = [(first - 0.6, last + 0.6) for first, last in mic.sounds_at]  # the pre-roll, the tail
            result.echo_onsets = sum(
                1
                for a in bench.activity_heard
                if a.msg.data and not any(lo <= a.at <= hi for lo, hi in sounds)
            )
            result.echo_pauses = sum(
                1
                for i in bench.interruptions
                if i.msg.action == 1 and not any(lo <= i.at <= hi for lo, hi in sounds)  # PAUSE
            )
            result.late_reference_samples = mic.late_reference_samples
        assert graph.wav is not None
        graph.processes[0].stop()  # the player: its WAV gets its header and its last block
        check_wav(graph.wav, result)
    return result


# --- the WAV against the reply -----------------------------------------------------------------


def check_wav(path: Path, result: ModeResult) -> None:
    """Walk the player's WAV: per trial (the warm-up first) the story as far as it played, then
    the answer. Any jump in the story's audio is audio lost (or repeated) at a pause."""
    with wave.open(str(path), "rb") as wav:
        played = np.frombuffer(wav.readframes(wav.getnframes()), dtype="<i2")
    story = np.frombuffer(speech_pcm(STORY, MS_PER_CHAR), dtype="<i2")
    answer = np.frombuffer(speech_pcm(ANSWER, MS_PER_CHAR), dtype="<i2")
    per_ms = OUTPUT_RATE // 1000
    position = 0
    for index, trial in enumerate([None, *result.trials]):
        position, consumed, jumps = align(played, position, story, answer)
        if index == 0:  # the warm-up
            pass
        else:
            assert trial is not None
            result.lost_ms.append(sum(jumps) / per_ms)
            if trial.story_cut:
                result.wav_vs_played_ms.append(consumed / per_ms - trial.story_played_ms)
        if not np.array_equal(played[position : position + len(answer)], answer):
            result.wav_problems.append(f"trial {index - 1}: the answer is not where the story ended")
            return
        position += len(answer)


def align(
    played: np.ndarray, position: int, story: np.ndarray, answer: np.ndarray
) -> tuple[int, int, list[int]]:
    """Follow the story in `played` from `position` until the answer begins: (where it ended,
    story samples heard, jumps in samples: > 0 skipped, < 0 repeated)."""
    window = OUTPUT_RATE // 10  # 100 ms must match after a jump
    reach = OUTPUT_RATE // 2
    cursor, heard = 0, 0
    jumps: list[int] = []
    while position < len(played) and cursor < len(story):
        span = min(len(played) - position, len(story) - cursor)
        same = played[position : position + span] == story[cursor : cursor + span]
        run = int(np.argmin(same)) if not same.all() else span
        position, cursor, heard = position + run, cursor + run, heard + run
        if run == span:
            break
        # the answer may have begun a little earlier: it starts from silence, as the story may end
        back = next(
            (
                b
                for b in range(min(run, OUTPUT_RATE // 50) + 1)
                if np.array_equal(played[position - b : position - b + len(answer)], answer)
            ),
            None,
        )
        if back is not None:
            return position - back, heard - back, jumps
        rest = played[position : position + window]
        jump = next(
            (
                d
                for d in sorted(range(-reach, reach + 1), key=abs)
                if 0 <= cursor + d and np.array_equal(story[cursor + d : cursor + d + len(rest)], rest)
            ),
            None,
        )
        if jump is None:  # the story is over in the WAV (its tail is the answer, or unknown)
            break
        jumps.append(jump)
        cursor += jump
    return position, heard, jumps


# --- the report --------------------------------------------------------------------------------


def emit(record: dict[str, Any]) -> None:
    print(json.dumps({"bench": "barge_in", **record}), flush=True)


def report(result: ModeResult, floor: float) -> list[tuple[str, list[float], str]]:
    mode = result.mode
    rows: list[tuple[str, list[float], str]] = []
    falses = [t.false for t in result.trials]
    reals = [t.real for t in result.trials if t.real is not None]
    for group, held_out in (("tuned", False), ("held_out", True)):
        for kind in ("noise", "cough", "backchannel"):
            heard = [h for h in falses if h.sound.kind == kind and h.sound.held_out == held_out]
            if not heard:
                continue
            emit(
                {
                    "mode": mode,
                    "figure": f"false_{kind}",
                    "voices": group,
                    "value": sum(h.outcome == "cut" for h in heard),
                    "unit": "confirmed",
                    "sounds": len(heard),
                    "onsets": sum(h.onset for h in heard),
                    "paused": sum(h.paused for h in heard),
                    "resumed": sum(h.outcome == "resumed" for h in heard),
                    "confirmed_labels": [
                        f"{h.sound.label}/{h.sound.voice}" for h in heard if h.outcome == "cut"
                    ],
                    "goal": 0,
                }
            )
        real = [h for h in reals if h.sound.held_out == held_out]
        if real:
            share = sum(h.outcome == "cut" for h in real) / len(real)
            emit(
                {
                    "mode": mode,
                    "figure": "real_interruptions_confirmed",
                    "voices": group,
                    "value": round(share, 3),
                    "unit": "share",
                    "sounds": len(real),
                    "missed": [f"{h.sound.label}/{h.sound.voice}" for h in real if h.outcome != "cut"],
                    "goal": f">= {GOAL_REAL_CONFIRMED}",
                }
            )
    everything = falses + reals
    onset_ms = [h.onset_to_paused_ms for h in everything if h.onset_to_paused_ms is not None]
    sound_ms = [h.sound_to_paused_ms for h in everything if h.sound_to_paused_ms is not None]
    unpaused = sum(h.onset and not h.paused for h in everything)
    emit(
        {
            "mode": mode,
            "figure": "speech_onset_to_player_paused_ms",
            **summary(onset_ms),
            "onsets_without_pause": unpaused,
            "goal_p95_ms": GOAL_PAUSE_P95_MS,
            "meets_goal": percentile(onset_ms, 95) <= GOAL_PAUSE_P95_MS,
            "p50_ratio_vs_floor": round(percentile(onset_ms, 50) / floor, 2),
            "floor_ms": round(floor, 2),
        }
    )
    emit({"mode": mode, "figure": "mic_sound_start_to_player_paused_ms", **summary(sound_ms)})
    resumed = [t for t in result.trials if t.false.outcome == "resumed"]
    lost = [ms for t, ms in zip(result.trials, result.lost_ms, strict=False) if t.false.outcome == "resumed"]
    emit(
        {
            "mode": mode,
            "figure": "audio_lost_at_resume_ms",
            **summary([abs(x) for x in lost]),
            "resumes": len(resumed),
            "over_one_block": sum(abs(x) > BLOCK_MS for x in lost),
            "any_jump_all_stories": sum(x != 0 for x in result.lost_ms),
            "goal_max_ms": BLOCK_MS,
            "wav_problems": result.wav_problems[:3],
        }
    )
    after_false = [t for t in result.trials if t.story_cut and t.truncate_ms is not None and t.false.paused]
    errors = [float(t.truncate_ms - t.story_played_ms) for t in after_false if t.truncate_ms is not None]
    emit(
        {
            "mode": mode,
            "figure": "truncate_minus_played_ms_after_false",
            **summary([abs(e) for e in errors]),
            "signed_min": min(errors, default=float("nan")),
            "signed_max": max(errors, default=float("nan")),
            "within_one_block": sum(abs(e) <= BLOCK_MS for e in errors),
            "goal_abs_ms": BLOCK_MS,
        }
    )
    wav_errors = [abs(x) for x in result.wav_vs_played_ms]
    emit(
        {
            "mode": mode,
            "figure": "wav_minus_played_ms_cut_stories",
            **summary(wav_errors),
            "within_one_block": sum(x <= BLOCK_MS for x in wav_errors),
        }
    )
    if mode == "aec":
        emit(
            {
                "mode": mode,
                "figure": "echo_onsets",
                "value": result.echo_onsets,
                "unit": "onsets with no user sound",
                "echo_pauses": result.echo_pauses,
                "late_reference_samples": result.late_reference_samples,
            }
        )
    rows += [
        (f"{mode}: voice_activity -> player paused", onset_ms, f"goal p95 <= {GOAL_PAUSE_P95_MS:g} ms"),
        (f"{mode}: mic sound start -> player paused", sound_ms, "incl. capture block + Silero"),
        (f"{mode}: |audio lost at resume|", [abs(x) for x in lost], f"goal <= {BLOCK_MS} ms"),
        (f"{mode}: |truncate - played| after false", [abs(e) for e in errors], f"goal <= {BLOCK_MS} ms"),
    ]
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--trials", type=int, default=16, help="false + real sounds per mode (one story each)"
    )
    parser.add_argument("--quick", action="store_true", help="6 trials, external only")
    parser.add_argument("--mode", choices=("external", "aec", "all"), default="all")
    parser.add_argument("--seed", type=int, default=34)
    args = parser.parse_args()
    trials = 6 if args.quick else args.trials
    if trials < 1:
        parser.error("--trials must be >= 1")
    modes = ("external",) if args.quick else ("external", "aec") if args.mode == "all" else (args.mode,)
    chunk = np.zeros(MIC_RATE * CHUNK_MS // 1000, dtype=np.int16)
    dds = dds_one_way_ms(40, chunk)
    ws = websocket_round_trip_ms(40, chunk)
    floor = 3 * percentile(dds, 50) + percentile(ws, 50)  # VAD→bridge, bridge→player, player→bench
    emit({"figure": "baseline_dds_publish_to_subscribe_ms", **summary(dds)})
    emit({"figure": "baseline_websocket_round_trip_ms", **summary(ws)})
    rows: list[tuple[str, list[float], str]] = []
    for mode in modes:
        started = time.monotonic()
        result = measure(mode, trials, args.seed)
        print(f"{mode}: {len(result.trials)} trials in {time.monotonic() - started:.0f} s", flush=True)
        rows += report(result, floor)
    rows += [
        ("baseline: DDS publish -> subscribe", dds, "one hop"),
        ("baseline: WebSocket round trip", ws, "one round trip"),
        ("transport floor (3 DDS + 1 WS)", [floor], "3 x DDS p50 + 1 x WS p50"),
    ]
    table(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
