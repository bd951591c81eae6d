"""Typed prompts (`prompt_text`) for the offline agent: the same meanings the recognizer hears,
without a recognizer.

A text turn is matched whole against the spoken forms generated from the command vocabulary and
the session's tool phrases (local_speech/spoken.py), so "look up" typed means what "look up" said
means, and "go to the kitchen" calls the tool whose phrase it is. A command typed in its
normal form ("pan@left") is accepted too; a bare bearing ("right") is not, for the reason the
spoken vocabulary leaves it out: alone it is agreement far more often than a command.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from by_your_command.commands.grammar import CommandGrammar
from by_your_command.commands.vocabulary import Vocabulary
from by_your_command.local_speech.recognizer import Recognition
from by_your_command.local_speech.spoken import (
    RecognitionKind,
    SpokenVocabularyConfig,
    build_spoken_forms,
)
from by_your_command.local_speech.tool_phrases import ToolPhrase

_NOT_WORDS = re.compile(r"[^a-z' ]+")
_EDGE = " \t.,;:!?\"'`"
# Politeness around a command, dropped before matching ("please look up", "stop now").
_LEADING = ("please", "robot", "hey robot", "okay", "ok")
_TRAILING = ("please", "now", "robot")


def rejected(text: str, reason: str) -> Recognition:
    return Recognition(RecognitionKind.REJECTED, text, "", 0.0, reason)


class TextMatcher:
    def __init__(
        self,
        vocabulary: Vocabulary,
        spoken: SpokenVocabularyConfig | None = None,
        tools: Sequence[ToolPhrase] = (),
    ) -> None:
        """`tools`: the tool phrases the recognizer hears (OfflineRecognizer.tools), typed the same."""
        config = spoken or SpokenVocabularyConfig()
        self._forms = {form.words: form for form in build_spoken_forms(vocabulary, config, tools)}
        self._phrases = frozenset(config.phrases)
        self._grammar = CommandGrammar(vocabulary)

    def understand(self, text: str) -> Recognition:
        """What a typed text means, as a Recognition (confidence 1: typing is not guessed)."""
        cleaned = " ".join(text.lower().split()).strip(_EDGE)
        words = _trim(" ".join(_NOT_WORDS.sub(" ", cleaned).split()))
        form = self._forms.get(words)
        if form is not None:
            return Recognition(form.kind, text, form.canonical, 1.0)
        parsed = self._grammar.parse_one(cleaned)
        command = parsed.command
        if command is None or command.spec.name != cleaned.partition("@")[0].split(" ")[0]:
            return rejected(text, "not a command, phrase or question")  # chat, or a bare bearing
        kind = RecognitionKind.PHRASE if command.spec.name in self._phrases else RecognitionKind.COMMAND
        return Recognition(kind, text, command.text, 1.0)


def _trim(words: str) -> str:
    for lead in _LEADING:
        if words.startswith(lead + " "):
            words = words[len(lead) + 1 :]
    for tail in _TRAILING:
        if words.endswith(" " + tail):
            words = words[: -len(tail) - 1]
    return words
