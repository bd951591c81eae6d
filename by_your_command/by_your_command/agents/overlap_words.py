"""The words said over the robot's voice, heard on the robot: does a barge-in say anything?

A cough or a knock is settled by its length (the VAD's voiced speech). "Uh-huh", "yeah" and
"okay" are as long as a short command but mean "go on", so a barge-in also needs words that are
not backchannels. The held audio (never sent anywhere before the verdict) is transcribed by
pocketsphinx (a dependency; its en-us model ships in the wheel) into a small vocabulary: the
backchannels and a few hundred everyday words, so other speech comes out as words of its own
rather than being forced into "okay". Decoding ~1 s of audio takes tens of milliseconds; the
runtime runs it off its loop. No rclpy here.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from by_your_command.vad.spoken_wake import GARBAGE_WORDS, SmallVocabulary, pronunciations

MAX_DECODE_S = 6.0  # a barge-in is judged within seconds: never decode more than this
BACKCHANNEL_WEIGHT = 10  # each backchannel phrase's share of the language model's text
_WORD = re.compile(r"[a-z']+")


def words_of(text: str) -> list[str]:
    """Lower-case words; hyphens split ("uh-huh" is "uh huh")."""
    return _WORD.findall(text.lower().replace("-", " "))


def interrupting_words(text: str, backchannels: Sequence[str]) -> list[str]:
    """The words of `text` that are not part of a backchannel phrase (longest phrase first)."""
    phrases = sorted({tuple(words_of(p)) for p in backchannels if words_of(p)}, key=len, reverse=True)
    words = words_of(text)
    kept: list[str] = []
    index = 0
    while index < len(words):
        match = next((p for p in phrases if tuple(words[index : index + len(p)]) == p), None)
        if match is None:
            kept.append(words[index])
            index += 1
        else:
            index += len(match)
    return kept


class LocalTranscriber:
    """pcm (int16 LE bytes) -> what pocketsphinx heard. Not thread-safe: one decode at a time."""

    def __init__(self, backchannels: Sequence[str]) -> None:
        dictionary = pronunciations()  # RecognizerUnavailableError without pocketsphinx
        chosen = [" ".join(words_of(p)) for p in backchannels]
        # "uh-huh" is one entry of the dictionary: keep the hyphenated forms it knows too
        hyphenated = [p.lower() for p in backchannels if "-" in p and p.lower() in dictionary]
        known = [p for p in [*chosen, *hyphenated] if p and all(w in dictionary for w in p.split())]
        vocabulary = sorted({w for w in GARBAGE_WORDS if w in dictionary})
        text = "\n".join(vocabulary + [p for p in known for _ in range(BACKCHANNEL_WEIGHT)]) + "\n"
        self._recognizer = SmallVocabulary(text, dictionary, MAX_DECODE_S)

    def __call__(self, pcm: bytes, sample_rate: int) -> str:
        return self._recognizer.transcribe(np.frombuffer(pcm, dtype="<i2"), sample_rate)
