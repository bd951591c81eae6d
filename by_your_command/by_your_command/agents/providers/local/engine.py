"""The offline speech engine as the offline provider uses it: load once, recognize, understand
typed text, say.

`LocalEngine` wraps the library in by_your_command/local_speech/ (pocketsphinx + espeak-ng). Loading
takes seconds (the acoustic model and the search), so it happens off the event loop, when the first
session connects, and the factory shares the loaded engine with every later session: a new session
costs nothing. Its methods block and are called from threads; a timed-out call may still run when
the next one starts, so each part is serialised (the recognizer has its own lock, the speaker gets
one here). Replies said before are kept (a few, bounded), and the not-heard reply is made at load:
saying them again runs no synthesis.

The robot's tools are heard too (`use_tools`): the recognizer is rebuilt with their phrases (the
provider selects and bounds them, local_speech/tool_phrases.py), off the event loop, only when
the set of phrases changes (a new session with the same tools costs nothing). The rebuild shares
the loaded models (OfflineRecognizer.with_tools); a decode already running finishes on the
recognizer it started on.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter, OrderedDict
from collections.abc import Sequence
from typing import Protocol, TypeVar

from by_your_command.agents.providers.local.config import OfflineConfig
from by_your_command.agents.providers.local.text import TextMatcher
from by_your_command.local_speech.recognizer import OfflineRecognizer, Recognition, RecognizerConfig
from by_your_command.local_speech.speaker import Speaker
from by_your_command.local_speech.tool_phrases import ToolPhrase

log = logging.getLogger(__name__)

T = TypeVar("T")
SAID_KEPT = 32  # replies whose audio is kept: acknowledgements and the not-heard reply recur


class Engine(Protocol):
    def load(self) -> None:
        """Blocking, idempotent; raises ImportError/OSError/ValueError when it cannot work."""

    def recognize(self, pcm: bytes, sample_rate: int) -> Recognition: ...

    def understand(self, text: str) -> Recognition: ...

    def say(self, text: str) -> tuple[bytes, int]:
        """Mono PCM16 LE and its sample rate; ValueError (nothing to say) or RuntimeError (espeak-ng
        failed) otherwise."""

    def use_tools(self, phrases: Sequence[ToolPhrase]) -> Counter[str]:
        """Blocking: recognize and understand hear these tool phrases from now on (and no others);
        returns those the recognizer left out (unpronounceable, already said for a command), by
        reason."""


class LocalEngine:
    def __init__(self, config: OfflineConfig) -> None:
        self._config = config
        self._load_lock = threading.Lock()
        self._speak_lock = threading.Lock()
        self._recognizer: OfflineRecognizer | None = None
        self._speaker: Speaker | None = None
        self._matcher: TextMatcher | None = None
        self._said: OrderedDict[str, tuple[bytes, int]] = OrderedDict()
        self._tools_lock = threading.Lock()
        self._tools: frozenset[ToolPhrase] = frozenset()  # what the recognizer hears now
        self._left_out: Counter[str] = Counter()
        self.rebuilds = 0  # recognizers built for a new set of tool phrases

    def load(self) -> None:
        with self._load_lock:
            if self._matcher is not None:
                return
            config = self._config
            recognizer = OfflineRecognizer(RecognizerConfig(commands_file=config.commands_file))
            self._speaker = Speaker(config.speaker())
            self._recognizer = recognizer
            # Typed text means what the same words mean spoken: the recognizer's vocabulary and forms.
            self._matcher = TextMatcher(recognizer.vocabulary, recognizer.config.spoken)
        if config.not_heard_text.strip():
            try:
                self.say(config.not_heard_text.strip())  # ready before the first chat line: said at once
            except (ValueError, RuntimeError):
                pass  # said (and its failure reported) when it is needed

    def use_tools(self, phrases: Sequence[ToolPhrase]) -> Counter[str]:
        with self._tools_lock:
            recognizer = self._loaded(self._recognizer)
            if frozenset(phrases) == self._tools:
                return Counter(self._left_out)
            hearing = recognizer.with_tools(phrases)
            matcher = TextMatcher(hearing.vocabulary, hearing.config.spoken, hearing.tools)
            self._recognizer, self._matcher = hearing, matcher  # one decode at a time takes either
            self._tools = frozenset(phrases)
            self._left_out = hearing.tools_left_out
            self.rebuilds += 1
            log.info(
                "offline: the recognizer hears %d tool phrase(s) of %d tool(s); left out: %s",
                len(hearing.tools),
                len({phrase.tool for phrase in hearing.tools}),
                dict(self._left_out) or "none",
            )
            return Counter(self._left_out)

    def recognize(self, pcm: bytes, sample_rate: int) -> Recognition:
        return self._loaded(self._recognizer).recognize(pcm, sample_rate)  # never raises on bad audio

    def understand(self, text: str) -> Recognition:
        return self._loaded(self._matcher).understand(text)

    def say(self, text: str) -> tuple[bytes, int]:
        speaker = self._loaded(self._speaker)
        with self._speak_lock:
            said = self._said.get(text)
            if said is None:
                said = self._said[text] = speaker.say(text)
                if len(self._said) > SAID_KEPT:
                    self._said.popitem(last=False)
            self._said.move_to_end(text)
            return said

    @staticmethod
    def _loaded(part: T | None) -> T:
        if part is None:
            raise RuntimeError("the offline engine is not loaded")
        return part
