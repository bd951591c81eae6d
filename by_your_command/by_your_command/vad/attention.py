"""Whether the VAD listens: awake / asleep (wake_cmd, phrases) and muted (voice_active=False)."""

from __future__ import annotations

import re
from collections.abc import Iterable
from enum import Enum


class AttentionState(str, Enum):
    AWAKE = "awake"
    ASLEEP = "asleep"
    MUTED = "muted"


class Attention:
    """Mute overrides sleep/wake without forgetting it: unmuting returns to awake or asleep."""

    def __init__(self, awake: bool = True) -> None:
        self._awake = awake
        self._muted = False

    @property
    def state(self) -> AttentionState:
        if self._muted:
            return AttentionState.MUTED
        return AttentionState.AWAKE if self._awake else AttentionState.ASLEEP

    @property
    def listening(self) -> bool:
        return self.state is AttentionState.AWAKE

    def set_awake(self, awake: bool) -> bool:
        """Returns True when the visible state changed."""
        before = self.state
        self._awake = awake
        return self.state is not before

    def set_muted(self, muted: bool) -> bool:
        before = self.state
        self._muted = muted
        return self.state is not before


class PhraseCommand(str, Enum):
    WAKE = "wake"
    SLEEP = "sleep"


# Politeness and attention-getters around a command ("please go to sleep now", "hey, wake up").
FILLER_WORDS = frozenset(
    {"please", "now", "hey", "hi", "ok", "okay", "alright", "so", "well", "oh", "um", "uh"}
)
# A text holding any of these is never a command: "don't go to sleep", "I can't sleep".
# (also every word ending in "n't": isn't, didn't, shouldn't...)
NEGATIONS = frozenset({"not", "no", "never", "dont", "cant", "cannot", "wont"})
# Commands are short: longer text is a sentence, and skipping it keeps a huge message cheap.
MAX_COMMAND_CHARS = 200

_WORD = re.compile(r"\w+(?:'\w+)*")


def words_of(text: str) -> list[str]:
    """Lower-case words, punctuation dropped; inner apostrophes kept ("don't"), curly ones folded."""
    return _WORD.findall(text.lower().replace("\u2019", "'").replace("\u2018", "'"))


def _negated(words: list[str]) -> bool:
    return any(word in NEGATIONS or word.endswith("n't") for word in words)


def _cuts(words: list[str], name: list[str]) -> list[int]:
    """How many words can be dropped from the front: filler words and the robot's name, repeatedly."""
    cuts = [0]
    while True:
        at = cuts[-1]
        if at < len(words) and words[at] in FILLER_WORDS:
            cuts.append(at + 1)
        elif name and words[at : at + len(name)] == name:
            cuts.append(at + len(name))
        else:
            return cuts


def _cores(words: list[str], name: list[str]) -> list[tuple[str, ...]]:
    """The text with any filler/name run cut from either end (the phrase itself may hold filler)."""
    back = _cuts(words[::-1], name[::-1])
    return [tuple(words[start : len(words) - end]) for start in _cuts(words, name) for end in back]


def _phrase_set(phrases: Iterable[str], kind: str) -> frozenset[tuple[str, ...]]:
    result = set()
    for phrase in phrases:
        words = words_of(phrase)
        if not words:
            raise ValueError(f"{kind} phrase {phrase!r} has no words")
        if _negated(words):
            raise ValueError(f"{kind} phrase {phrase!r} holds a negation: negated text never matches")
        result.add(tuple(words))
    return frozenset(result)


class PhraseMatcher:
    """Says whether a whole text is a wake or sleep command.

    The text must be exactly one configured phrase once case, punctuation, filler words and the
    robot's name at its edges are removed: "Please go to sleep now!" sleeps, "I can't sleep",
    "How did you sleep?" and "Don't go to sleep!" do not. Questions (a '?') and negations never match.
    """

    def __init__(
        self, wake_phrases: Iterable[str], sleep_phrases: Iterable[str], robot_name: str = ""
    ) -> None:
        self._wake = _phrase_set(wake_phrases, "wake")
        self._sleep = _phrase_set(sleep_phrases, "sleep")
        both = self._wake & self._sleep
        if both:
            raise ValueError(f"phrases both wake and sleep: {sorted(' '.join(p) for p in both)}")
        self._name = words_of(robot_name)

    def match(self, text: str) -> PhraseCommand | None:
        if len(text) > MAX_COMMAND_CHARS or "?" in text:
            return None
        words = words_of(text)
        if _negated(words):
            return None
        for core in _cores(words, self._name):
            if core in self._wake:
                return PhraseCommand.WAKE
            if core in self._sleep:
                return PhraseCommand.SLEEP
        return None
