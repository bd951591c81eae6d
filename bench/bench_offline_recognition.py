"""Offline recognition accuracy: commands recognized exactly, chat never turned into a command.

Corpus, synthesized now with espeak-ng in voices the recognizer was NOT tuned on (tuning used
other espeak voices and variants: en-us, en-gb, en-gb-scotland, en-gb-x-gbclan, en-gb-x-gbcwmd,
en-us-nyc; variants m1-m5, f1, f2, f4, f5, klatt; other speeds and pitches; a second unseen
set, run for docs/offline.md: --voices en-us+m6 en-gb+m8 en-us+Annie en-029+m3): every command,
phrase and question of the vocabulary in up to two spoken forms (each form said by two of the
held-out voices), one polite form of every command ("can you look up please", tallied apart as
"polite ..."), and CHAT lines (small talk, questions, sentences holding command words, command
words in other sentences) and HOLDING lines, chat that holds a form's words but does not ask for
it ("I turned left", "don't look up"; tallied apart as "holding ..."), each clean and with noise at
--snr dB: white (the default), pink (--noise pink: most room and machine noise) or babble (--noise
babble: four other voices talking at once). --room RT60 puts every utterance in a reverberant room
first (a statistical room response: the direct sound and a tail of reflections decaying 60 dB in
RT60 seconds, --drr dB below the direct sound; 0.5 s and 0 dB is a living room with the speaker
about a metre from the microphone).
Every search decodes the same audio through OfflineRecognizer in the same run: Moonshine
with pocketsphinx as second opinion (what ships), pocketsphinx verified (the fallback without the
Moonshine model) and a bare JSGF grammar (baseline). Figures as JSON lines (decode speed as the
median real-time factor per utterance and its ratio to the baseline's), then a table, the missed
commands and the chat lines taken.
Another synthesizer, flite (`apt install flite`): --voices flite:slt flite:rms flite:awb flite:kal16.
usage: scripts/run.sh python bench/bench_offline_recognition.py [--forms 2] [--snr 15] [--noise white]
       [--room 0.5 --drr 0] [--voices ...] [--searches moonshine verified bare_grammar]
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import functools
import json
import math
import pathlib
import random
import statistics
import subprocess
import tempfile
import time
from typing import Any

import numpy as np
import numpy.typing as npt

from by_your_command.audio.pcm import Int16Array, resample
from by_your_command.local_speech.recognizer import OfflineRecognizer, Recognition, RecognizerConfig, Search
from by_your_command.local_speech.spoken import RecognitionKind, SpokenForm

RATE = 16000
HELD_OUT_VOICES = ("en-us+f3", "en-us+m7", "en-gb-x-rp", "en-029")
FLITE = "flite:"
CHAT = (
    "I looked up the answer yesterday", "don't stop believing", "hello there, how are you today",
    "what a lovely morning", "can you hear me", "I think it might rain later", "my phone is out of battery",
    "turn the music down a little", "the cat is sleeping on the sofa", "let's go out for lunch",
    "I need to wake up earlier tomorrow", "do you like pizza", "where did I put my keys",
    "that was a really good movie", "thank you very much", "how old are you", "tell me a joke",
    "I am looking for the kitchen", "she turned left at the corner", "nice to meet you",
    "the weather is terrible", "I can't sleep at night", "please be quiet", "what do you see",
    "is it going to snow", "how far is the station", "my favourite colour is blue",
    "he tracked the package online", "we should follow the recipe", "good night everyone",
    "are you a robot", "that sounds great", "I have a question about dinner", "yes of course",
    "no thanks", "open the door please", "what is the capital of France", "play some music",
    "I left my bag on the bus", "reach for the stars", "look at that bird", "the panda is eating bamboo",
    "sorry I was not listening", "could you repeat that", "the stock market went up today",
    "move over, let me sit down", "I'm going to the shop", "bumper cars are fun", "right, okay then",
    "the meeting starts at nine", "how do you spell that", "I forgot my umbrella",
    # Command words in everyday sentences: a recognizer that spots words instead of whole forms
    # turns these into commands.
    "look over there", "looking good", "turn up the heat", "pan out the camera", "move along",
    "follow up tomorrow", "track my order", "wake up call", "sleep well", "stop by later", "I'm freezing",
    "help me with my homework", "who is that", "what time does it open", "right behind you",
    "the left lane is slow", "back to work", "lookout point", "bumper sticker", "reach out to me",
    "look at the time", "I'll look into it", "can you look up a recipe", "the pan is still hot",
    "turn it off and on again", "we moved here last year", "track and field is my sport", "follow the money",
    "what's up", "look who's here", "hold on a second", "I left it on the table", "back in a minute",
    "the lookout tower is closed", "the ball is red", "stop and think about it", "wake me up at seven",
    "go to sleep little baby", "pan fried noodles", "turn right at the lights", "move the chair forward",
    "he reached the top", "attention to detail matters", "help yourself to cake", "freeze the leftovers",
    "halt and catch fire is a show", "ten hot dogs please",
)  # fmt: skip
# Chat that holds a form's words but does not ask for it: telling of the action, forbidding it,
# making it a condition. Tallied apart ("holding ..."), after everything else, so the other
# figures compare across versions.
HOLDING = (
    "I turned left", "she turned to the right", "we turned around", "it turned back", "you turned right",
    "I moved forward", "they moved left", "he moved back", "I'm moving forward", "we moved to the right",
    "I looked up", "she looked up to the left", "he looked out", "they were looking up",
    "I'm looking out ahead", "I reached forward", "she reached to the left", "he reaches back",
    "I followed the ball", "they followed me", "he follows the person", "we tracked the ball",
    "she's tracking me", "the camera panned left", "it pans to the right", "I stopped",
    "it stopped moving", "the car stopped", "he froze", "I woke up", "she wakes up early",
    "the baby slept", "he went to sleep", "they stood at attention", "you moved back",
    "I'm turning right", "don't turn left", "do not move forward", "don't look up", "never follow me",
    "if you turn left", "when you look up",
)  # fmt: skip
BASELINE = Search.BARE_GRAMMAR
COMMAND_KINDS = (RecognitionKind.COMMAND, RecognitionKind.PHRASE)


@dataclasses.dataclass(frozen=True)
class Utterance:
    text: str
    voice: str
    expected: SpokenForm | None  # None: chat, must be rejected
    holding: bool = False  # chat holding a form's words (HOLDING)

    @property
    def group(self) -> str:
        """Polite commands and chat holding a form's words are tallied apart, so the main figures
        compare across versions."""
        if self.holding:
            return "holding "
        return "polite " if self.expected is not None and self.expected.polite else ""


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    record = {"bench": "offline_recognition", "figure": figure, "value": round(value, 4), "unit": unit}
    print(json.dumps({**record, **extra}), flush=True)


def synthesize(text: str, voice: str, words_per_minute: int = 150, pitch: int | None = None) -> Int16Array:
    """espeak-ng's speech at RATE (pitch 0-99; None: the voice's own); "flite:<voice>" is flite's."""
    if voice.startswith(FLITE):
        return _flite(text, voice.removeprefix(FLITE))
    pitch_option = [] if pitch is None else ["-p", str(pitch)]
    wav = subprocess.run(
        ["espeak-ng", "-v", voice, "-s", str(words_per_minute), *pitch_option, "--stdout", "--stdin"],
        input=text.encode(),
        capture_output=True,
        check=True,
        timeout=30,
    ).stdout
    return _pcm(wav)


def _flite(text: str, voice: str) -> Int16Array:
    """flite (`apt install flite`): another synthesizer, with voices built from recorded speech."""
    with tempfile.TemporaryDirectory() as folder:
        wav_path = pathlib.Path(folder, "speech.wav")
        command = ["flite", "-voice", voice, "-o", str(wav_path)]  # the text on stdin
        subprocess.run(command, input=text.encode(), check=True, timeout=30)
        return _pcm(wav_path.read_bytes())


def _pcm(wav: bytes) -> Int16Array:
    """A canonical 44-byte-header mono WAV (what both synthesizers write) resampled to RATE."""
    rate = int.from_bytes(wav[24:28], "little")
    return resample(np.frombuffer(wav[44:], dtype="<i2").astype(np.int16), rate, RATE)


def with_noise(speech: Int16Array, snr_db: float, seed: int, noise: str = "white") -> Int16Array:
    """Noise (NOISES) at snr_db below the speech's power, also 0.3 s before and after (VAD pre-roll)."""
    rng = np.random.default_rng(seed)
    signal = speech.astype(np.float64)
    active = signal[np.abs(signal) > 300]
    power = float(np.mean(active**2)) if len(active) else 1.0
    pad = int(0.3 * RATE)
    mixed = NOISES[noise](len(signal) + 2 * pad, rng) * math.sqrt(power / 10 ** (snr_db / 10))
    mixed[pad : pad + len(signal)] += signal
    return np.clip(mixed, -32768, 32767).astype(np.int16)


def _white(samples: int, rng: np.random.Generator) -> npt.NDArray[np.float64]:
    return rng.normal(0.0, 1.0, samples)


def _pink(samples: int, rng: np.random.Generator) -> npt.NDArray[np.float64]:
    """Power falling 3 dB per octave, like most room and machine noise (fan, traffic, wind)."""
    spectrum = np.fft.rfft(rng.normal(0.0, 1.0, samples))
    frequency = np.fft.rfftfreq(samples, 1 / RATE)
    spectrum /= np.sqrt(np.maximum(frequency, 20.0))  # flat below 20 Hz
    pink = np.fft.irfft(spectrum, samples)
    return pink / max(float(np.std(pink)), 1e-12)


@functools.cache
def _talkers() -> tuple[npt.NDArray[np.float64], ...]:
    """Four streams of chat, for babble, in voice and variant pairs no benchmark or tuning run uses."""
    voices = ("en-us+m3", "en-gb+f3", "en-us+f4", "en-gb-scotland+m6")
    streams = []
    for turn, voice in enumerate(voices):
        lines = CHAT[turn::4][:12]
        streams.append(np.concatenate([synthesize(line, voice).astype(np.float64) for line in lines]))
    return tuple(stream / max(float(np.std(stream)), 1e-12) for stream in streams)


def _babble(samples: int, rng: np.random.Generator) -> npt.NDArray[np.float64]:
    """Four people talking at once in the background (a TV, a room), each at a random point."""
    mixed = np.zeros(samples)
    for stream in _talkers():
        start = int(rng.integers(0, max(len(stream) - samples, 1)))
        mixed += np.resize(stream[start:], samples)
    return mixed / max(float(np.std(mixed)), 1e-12)


NOISES = {"white": _white, "pink": _pink, "babble": _babble}


def in_room(speech: Int16Array, rt60_s: float, direct_to_reverberant_db: float, seed: int) -> Int16Array:
    """Speech as a microphone across a room hears it: the direct sound, then a diffuse tail of
    reflections decaying 60 dB in rt60_s (exponentially decaying noise, the usual statistical room
    model), its energy direct_to_reverberant_db below the direct sound's; the tail runs on after
    the speech, as in a VAD segment. Scaled back to the dry speech's peak level."""
    rng = np.random.default_rng(seed)
    length = int(rt60_s * RATE)
    time_s = np.arange(length) / RATE
    response = rng.normal(0.0, 1.0, length) * np.exp(-6.9 * time_s / rt60_s)  # 10**-3 at rt60_s: -60 dB
    response[: int(0.003 * RATE)] = 0.0  # the first reflection arrives ~1 m of path after the direct sound
    response *= math.sqrt(10 ** (-direct_to_reverberant_db / 10) / float(np.sum(response**2)))
    response[0] = 1.0  # the direct sound
    wet = np.convolve(speech.astype(np.float64), response)
    wet *= float(np.max(np.abs(speech))) / max(float(np.max(np.abs(wet))), 1e-9)
    return np.clip(wet, -32768, 32767).astype(np.int16)


def room_condition(rt60_s: float, direct_to_reverberant_db: float) -> str:
    """The tally name of a room (in_room): "room0.5 drr0"."""
    return f"room{rt60_s:g} drr{direct_to_reverberant_db:g}"


def add_room_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--room", type=float, default=0.0, help="reverberation time RT60 in seconds (default 0: no room)"
    )
    parser.add_argument(
        "--drr", type=float, default=0.0, help="with --room: direct-to-reverberant ratio, dB (default 0)"
    )


def room_of(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[float, float] | None:
    """The room the arguments ask for (RT60 s, direct-to-reverberant dB), None for none."""
    if (args.room and not 0.05 <= args.room <= 3) or not math.isfinite(args.drr):
        parser.error("--room takes 0 (no room) or 0.05 to 3 seconds, --drr a finite dB value")
    return (args.room, args.drr) if args.room else None


def noise_condition(noise: str, snr_db: float) -> str:
    """The tally name of a noisy condition: "snr15" for white noise (as in every earlier run),
    "pink15", "babble15"."""
    return f"snr{snr_db:g}" if noise == "white" else f"{noise}{snr_db:g}"


def corpus(forms: list[SpokenForm], voices: tuple[str, ...], per_command: int) -> list[Utterance]:
    """Up to `per_command` plain forms of every meaning, each said by two voices; the chat lines
    by all; one polite form of every command meaning ("can you look up please") said by one."""
    by_meaning: dict[str, list[SpokenForm]] = collections.defaultdict(list)
    polite: dict[str, list[SpokenForm]] = collections.defaultdict(list)
    for form in forms:
        (polite if form.polite else by_meaning)[f"{form.kind.value}:{form.canonical}"].append(form)
    chooser = random.Random(0)
    utterances = []
    turn = 0
    for meaning in sorted(by_meaning):
        choices = by_meaning[meaning]
        for form in chooser.sample(choices, min(per_command, len(choices))):
            for _ in range(2):  # two voices per form, rotating through the held-out ones
                utterances.append(Utterance(form.words, voices[turn % len(voices)], form))
                turn += 1
    utterances += [Utterance(text, voice, None) for text in CHAT for voice in voices]
    # Last, so that every other utterance keeps its place and with it its noise (seeded by it).
    polite_chooser = random.Random(1)
    for turn, meaning in enumerate(sorted(polite)):
        form = polite_chooser.choice(polite[meaning])
        utterances.append(Utterance(form.words, voices[turn % len(voices)], form))
    utterances += [Utterance(text, voice, None, holding=True) for text in HOLDING for voice in voices]
    return utterances


@dataclasses.dataclass
class Tally:
    commands: int = 0
    exact: int = 0
    chat: int = 0
    chat_as_command: int = 0
    chat_as_question: int = 0
    wrong_commands: int = 0  # a command heard as another command: acted on, wrongly
    audio_s: float = 0.0
    decode_s: float = 0.0
    rtf: list[float] = dataclasses.field(default_factory=list)  # per utterance
    misses: list[str] = dataclasses.field(default_factory=list)
    chat_taken: list[str] = dataclasses.field(default_factory=list)  # listed apart from the misses
    per_voice: collections.Counter[str] = dataclasses.field(default_factory=collections.Counter)
    per_voice_total: collections.Counter[str] = dataclasses.field(default_factory=collections.Counter)


def measure(
    recognizers: dict[Search, OfflineRecognizer], audio: list[tuple[Utterance, str, Int16Array]]
) -> dict[Search, dict[str, Tally]]:
    """Every search decodes each utterance in turn, so machine load falls on all of them alike."""
    tallies: dict[Search, dict[str, Tally]] = {
        search: collections.defaultdict(Tally) for search in recognizers
    }
    for utterance, condition, pcm in audio:
        for search, recognizer in recognizers.items():
            start = time.perf_counter()
            result = recognizer.recognize(pcm.tobytes(), RATE)
            elapsed = time.perf_counter() - start
            for key in (condition, "all"):
                tally = tallies[search][utterance.group + key]
                count(tally, utterance, condition, result, len(pcm) / RATE, elapsed)
    return tallies


def count(
    tally: Tally, utterance: Utterance, condition: str, result: Recognition, seconds: float, elapsed: float
) -> None:
    tally.audio_s += seconds
    tally.decode_s += elapsed
    tally.rtf.append(elapsed / seconds)
    expected = utterance.expected
    if expected is None:
        tally.chat += 1
        tally.chat_as_command += result.kind in COMMAND_KINDS
        tally.chat_as_question += result.kind is RecognitionKind.QUESTION
        if result.kind is not RecognitionKind.REJECTED:
            tally.chat_taken.append(
                f"chat {utterance.text!r} ({utterance.voice}, {condition}) -> {result.canonical}"
            )
        return
    tally.commands += 1
    hit = (result.kind, result.canonical) == (expected.kind, expected.canonical)
    tally.exact += hit
    tally.per_voice_total[utterance.voice] += 1
    tally.per_voice[utterance.voice] += hit
    if not hit:
        tally.wrong_commands += result.kind in COMMAND_KINDS
        tally.misses.append(f"{utterance.text!r} ({utterance.voice}, {condition}) -> {result.text!r}")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--forms", type=int, default=2, help="spoken forms per command (default 2)")
    parser.add_argument("--snr", type=float, default=15.0, help="noise condition, dB SNR (default 15)")
    parser.add_argument("--noise", choices=sorted(NOISES), default="white", help="noise kind (default white)")
    add_room_arguments(parser)
    parser.add_argument("--voices", nargs="+", default=list(HELD_OUT_VOICES))
    parser.add_argument(
        "--misses", type=int, default=15, help="missed commands and chat lines taken listed per search"
    )
    parser.add_argument(
        "--searches",
        nargs="+",
        type=Search,
        default=[Search.MOONSHINE, Search.VERIFIED, BASELINE],
        help="searches to compare (the baseline is always added)",
    )
    args = parser.parse_args()
    room = room_of(parser, args)

    searches: dict[Search, OfflineRecognizer] = {}
    for search in dict.fromkeys([*args.searches, BASELINE]):
        start = time.perf_counter()
        recognizer = OfflineRecognizer(RecognizerConfig(search=search))
        if recognizer.search is not search:
            raise SystemExit(f"{search.value} is not available here (it would run {recognizer.search.value})")
        emit("load", time.perf_counter() - start, "s", search=search.value)
        searches[search] = recognizer
    utterances = corpus(searches[BASELINE].forms, tuple(args.voices), args.forms)
    prefix = "" if room is None else room_condition(*room) + " "
    quiet, noisy = f"{prefix}clean", prefix + noise_condition(args.noise, args.snr)
    start = time.perf_counter()
    audio: list[tuple[Utterance, str, Int16Array]] = []
    for index, utterance in enumerate(utterances):
        speech = synthesize(utterance.text, utterance.voice)
        if room is not None:
            speech = in_room(speech, *room, index)
        audio += [
            (utterance, quiet, speech),
            (utterance, noisy, with_noise(speech, args.snr, index, args.noise)),
        ]
    kinds = collections.Counter(
        u.group.strip() or ("chat" if u.expected is None else "command") for u in utterances
    )
    emit("corpus", len(audio), "utterances", commands=2 * kinds["command"],
         polite_commands=2 * kinds["polite"], chat=2 * kinds["chat"], holding=2 * kinds["holding"],
         voices=args.voices,
         synth_s=round(time.perf_counter() - start, 1))  # fmt: skip

    results = measure(searches, audio)
    rows = []
    for search, tallies in results.items():
        for condition, tally in tallies.items():
            accuracy = 100.0 * tally.exact / max(tally.commands, 1)
            rtf = tally.decode_s / max(tally.audio_s, 1e-9)
            extra = {"search": search.value, "condition": condition}
            emit("exact_commands", accuracy, "%", n=tally.commands, **extra)
            emit("chat_as_command", tally.chat_as_command, "lines", n=tally.chat, **extra)
            emit("chat_as_question", tally.chat_as_question, "lines", n=tally.chat, **extra)
            emit("wrong_commands", tally.wrong_commands, "utterances", n=tally.commands, **extra)
            emit("decode_speed", rtf, "x real time", **extra)
            median = statistics.median(tally.rtf)
            baseline = statistics.median(results[BASELINE][condition].rtf)
            emit("decode_speed_median", median, "x real time", ratio_to_baseline=round(median / baseline, 2),
                 **extra)  # fmt: skip
            rows.append((search.value, condition, accuracy, tally.chat_as_command, tally.chat_as_question,
                         tally.chat, median))  # fmt: skip
        for voice, total in sorted(tallies["all"].per_voice_total.items()):
            emit("exact_commands_by_voice", 100.0 * tallies["all"].per_voice[voice] / total, "%",
                 search=search.value, voice=voice, n=total)  # fmt: skip

    print(f"\n{'search':<14}{'condition':<14}{'exact cmds':>11}{'chat->cmd':>11}{'chat->q':>9}{'RTF med':>9}")
    for search_name, condition, accuracy, as_command, as_question, chat, rtf in rows:
        print(f"{search_name:<14}{condition:<14}{accuracy:>10.1f}%{as_command:>6}/{chat:<4}"
              f"{as_question:>5}/{chat:<3}{rtf:>9.3f}")  # fmt: skip
    for search, tallies in results.items():
        misses = tallies["all"].misses + tallies["polite all"].misses
        chat_taken = tallies["all"].chat_taken + tallies["holding all"].chat_taken
        print(
            f"\n{search.value}: {len(misses)} missed commands" + (f", first {args.misses}:" if misses else "")
        )
        for miss in misses[: args.misses]:
            print(f"  {miss}")
        print(f"{search.value}: {len(chat_taken)} chat lines taken as a command or question")
        for line in chat_taken[: args.misses]:
            print(f"  {line}")


if __name__ == "__main__":
    main()
