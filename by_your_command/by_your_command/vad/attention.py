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


def _normalise(text: str) -> str:
    return " ".join(re.sub(r"[^\w']+", " ", text.lower()).split())


def _pattern(phrases: Iterable[str]) -> re.Pattern[str] | None:
    words = [_normalise(p) for p in phrases]
    alternatives = sorted({w for w in words if w}, key=len, reverse=True)
    if not alternatives:
        return None
    body = "|".join(r"\s+".join(map(re.escape, phrase.split())) for phrase in alternatives)
    # Whole words only: "awake" must not match "wake", "sleepy" must not match "sleep".
    return re.compile(rf"(?<![\w'])(?:{body})(?![\w'])")


class PhraseMatcher:
    """Finds wake or sleep phrases in typed text; wake wins when both occur."""

    def __init__(self, wake_phrases: Iterable[str], sleep_phrases: Iterable[str]) -> None:
        self._wake = _pattern(wake_phrases)
        self._sleep = _pattern(sleep_phrases)

    def match(self, text: str) -> PhraseCommand | None:
        normalised = _normalise(text)
        if self._wake is not None and self._wake.search(normalised):
            return PhraseCommand.WAKE
        if self._sleep is not None and self._sleep.search(normalised):
            return PhraseCommand.SLEEP
        return None
