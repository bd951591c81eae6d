"""Offline recognition on recorded people: folders of WAV files named for what was said.

Layout (Google Speech Commands' own, so its test set works as unpacked): DIR/<words>/*.wav, where
<words> is what the clips say, words joined by "_" ("stop", "look_up", "what_time_is_it"). A folder
whose words are a spoken form of the vocabulary (docs/offline.md) must be recognized as that form's
meaning; every other folder ("up", "left", "go", "_unknown_", "_silence_", a chat line) must be
rejected, and a clip of it turned into a command is the failure that matters most.

Not in `make bench`: recordings of people are not shipped and nothing is downloaded. The figures in
docs/offline.md are for the Speech Commands v0.02 test set (Warden 2018, CC BY 4.0; 4890 one-second
clips of single words by many people on their own microphones; speech_commands_test_set_v0.02 at
download.tensorflow.org/data). Record your own people and room the same way, one folder per form
or chat line.

Every clip is decoded by the shipped search and by the bare JSGF grammar (the baseline) in turn,
so machine load falls on both alike. Figures as JSON lines (decode speed as the median real-time
factor and its ratio to the baseline's), then one row per folder, the clips taken as another
meaning, and a form's clips rejected (with what Moonshine and pocketsphinx heard).
usage: scripts/run.sh python bench/offline_recordings.py DIR [--per-folder N] [--list 40]
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import random
import statistics
import time
import wave
from pathlib import Path
from typing import Any

from by_your_command.local_speech.recognizer import OfflineRecognizer, Recognition, RecognizerConfig, Search
from by_your_command.local_speech.spoken import RecognitionKind

BASELINE = Search.BARE_GRAMMAR
COMMAND_KINDS = (RecognitionKind.COMMAND, RecognitionKind.PHRASE)


@dataclasses.dataclass
class Folder:
    name: str
    expected: tuple[RecognitionKind, str] | None  # None: must be rejected
    clips: int = 0
    right: int = 0  # the expected meaning; for a folder of no form, rejected
    as_command: int = 0  # taken as a command or phrase it does not say
    as_question: int = 0
    taken: collections.Counter[str] = dataclasses.field(default_factory=collections.Counter)
    rtf: list[float] = dataclasses.field(default_factory=list)


def emit(figure: str, value: float, unit: str, **extra: Any) -> None:
    record = {"bench": "offline_recordings", "figure": figure, "value": round(value, 4), "unit": unit}
    print(json.dumps({**record, **extra}), flush=True)


def read_clip(path: Path) -> tuple[bytes, int]:
    """A WAV file's mono 16-bit PCM and rate; ValueError for anything else."""
    with wave.open(str(path)) as file:
        if file.getnchannels() != 1 or file.getsampwidth() != 2:
            raise ValueError(f"{path}: not mono 16-bit PCM")
        return file.readframes(file.getnframes()), file.getframerate()


def clips_by_folder(root: Path, per_folder: int | None) -> dict[str, list[Path]]:
    """Each folder's WAV files, at most `per_folder` of them drawn at random (seeded: the same
    draw every run)."""
    folders = {}
    for folder in sorted(path for path in root.iterdir() if path.is_dir()):
        clips = sorted(folder.glob("*.wav"))
        if per_folder is not None and len(clips) > per_folder:
            clips = sorted(random.Random(folder.name).sample(clips, per_folder))
        if clips:
            folders[folder.name] = clips
    return folders


def count(folder: Folder, result: Recognition, seconds: float, elapsed: float) -> None:
    folder.clips += 1
    folder.rtf.append(elapsed / seconds)
    meaning = (result.kind, result.canonical)
    if result.kind is not RecognitionKind.REJECTED:
        folder.taken[result.canonical] += 1
    if folder.expected is None:
        folder.right += result.kind is RecognitionKind.REJECTED
    else:
        folder.right += meaning == folder.expected
    if meaning != folder.expected:
        folder.as_command += result.kind in COMMAND_KINDS
        folder.as_question += result.kind is RecognitionKind.QUESTION


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "root", type=Path, help="a folder of folders of WAV files, each named for what it says"
    )
    parser.add_argument(
        "--per-folder", type=int, help="at most this many clips of each folder (default: all)"
    )
    parser.add_argument("--list", type=int, default=40, help="clips listed per search and kind of mistake")
    parser.add_argument("--searches", nargs="+", type=Search, default=[Search.MOONSHINE])
    args = parser.parse_args()
    if not args.root.is_dir():
        parser.error(f"{args.root} is not a folder")

    recognizers: dict[Search, OfflineRecognizer] = {}
    for search in dict.fromkeys([*args.searches, BASELINE]):
        recognizer = OfflineRecognizer(RecognizerConfig(search=search))
        if recognizer.search is not search:
            raise SystemExit(f"{search.value} is not available here (it would run {recognizer.search.value})")
        recognizers[search] = recognizer
    meanings = {form.words: (form.kind, form.canonical) for form in recognizers[BASELINE].forms}
    clips = clips_by_folder(args.root, args.per_folder)
    if not clips:
        raise SystemExit(f"no WAV files in the folders of {args.root}")

    results = {
        search: {name: Folder(name, meanings.get(name.replace("_", " ").lower())) for name in clips}
        for search in recognizers
    }
    wrong: dict[Search, list[str]] = collections.defaultdict(list)
    missed: dict[Search, list[str]] = collections.defaultdict(list)  # a form's clips rejected
    unreadable, done, total = 0, 0, sum(len(paths) for paths in clips.values())
    for name, paths in clips.items():
        for path in paths:
            done += 1
            print(f"decoding {done} of {total}", end="\r", flush=True)
            try:
                pcm, rate = read_clip(path)
            except (ValueError, EOFError, wave.Error) as error:
                unreadable += 1
                print(f"skipped {path}: {error!r}")
                continue
            seconds = len(pcm) / 2 / rate
            for search, recognizer in recognizers.items():
                start = time.perf_counter()
                result = recognizer.recognize(pcm, rate)
                folder = results[search][name]
                count(folder, result, seconds, time.perf_counter() - start)
                if (
                    result.kind is not RecognitionKind.REJECTED
                    and (result.kind, result.canonical) != folder.expected
                ):
                    wrong[search].append(f"{name}/{path.name} -> {result.canonical} ({result.text!r})")
                if folder.expected is not None and result.kind is RecognitionKind.REJECTED:
                    heard = f" ({result.text})" if result.text else ""
                    missed[search].append(f"{name}/{path.name}: {result.reason}{heard}")
    decoded = total - unreadable
    emit("clips", decoded, "clips", folders=len(clips), unreadable=unreadable)
    if not decoded:
        raise SystemExit("no clip could be read")

    for search, folders in results.items():
        forms = [folder for folder in folders.values() if folder.expected is not None]
        others = [folder for folder in folders.values() if folder.expected is None]
        extra = {"search": search.value}
        if forms:
            said = sum(folder.clips for folder in forms)
            emit("forms_exact", 100.0 * sum(f.right for f in forms) / max(said, 1), "%", n=said, **extra)
            emit("forms_as_other_command", sum(f.as_command for f in forms), "clips", n=said, **extra)
        if others:
            said = sum(folder.clips for folder in others)
            emit("others_as_command", sum(f.as_command for f in others), "clips", n=said, **extra)
            emit("others_as_question", sum(f.as_question for f in others), "clips", n=said, **extra)
        median = statistics.median(rtf for folder in folders.values() for rtf in folder.rtf)
        baseline = statistics.median(rtf for folder in results[BASELINE].values() for rtf in folder.rtf)
        emit(
            "decode_speed_median",
            median,
            "x real time",
            ratio_to_baseline=round(median / baseline, 2),
            **extra,
        )

    header = f"{'search':<14}{'folder':<18}{'expected':<16}{'clips':>6}{'right':>8}{'->cmd':>7}{'->q':>5}"
    print(f"\n{header}  taken as")
    for search, folders in results.items():
        for folder in folders.values():
            expected = "-" if folder.expected is None else folder.expected[1]
            right = 100.0 * folder.right / max(folder.clips, 1)
            taken = ", ".join(f"{canonical} {n}" for canonical, n in folder.taken.most_common(4))
            print(f"{search.value:<14}{folder.name:<18}{expected:<16}{folder.clips:>6}{right:>7.1f}%"
                  f"{folder.as_command:>7}{folder.as_question:>5}  {taken}")  # fmt: skip
    for search in recognizers:
        for what, lines in (
            ("taken as another meaning", wrong[search]),
            ("of a form rejected", missed[search]),
        ):
            print(f"\n{search.value}: {len(lines)} clips {what}" + (":" if lines else ""))
            for line in lines[: args.list]:
                print(f"  {line}")


if __name__ == "__main__":
    main()
