"""Access to the committed speech corpus (test/data/corpus, made by test/data/make_corpus.sh)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from by_your_command.audio.pcm import Int16Array, read_wav

CORPUS_DIR = Path(__file__).resolve().parents[1] / "data" / "corpus"


@dataclass(frozen=True)
class Segment:
    start: float
    end: float
    text: str


@dataclass(frozen=True)
class Session:
    name: str
    path: Path
    segments: list[Segment]

    def audio(self) -> Int16Array:
        pcm, rate, channels = read_wav(self.path)
        assert (rate, channels) == (16000, 1)
        return pcm


def sessions() -> list[Session]:
    meta = json.loads((CORPUS_DIR / "segments.json").read_text())
    return [
        Session(name, CORPUS_DIR / f"{name}.wav", [Segment(**s) for s in info["segments"]])
        for name, info in sorted(meta["sessions"].items())
    ]
