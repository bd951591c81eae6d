"""Parameters of the safety stop spotter: the one place their defaults live.

The VAD node declares them as its `stop_*` parameters (vad/config.py builds a StopConfig from
them), so a bad value stops the node at start with the message raised here.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

# Stop phrases per language. Only languages whose acoustic model ships with pocketsphinx can be
# spotted on the robot (its wheel holds en-us only): any other name is refused at start.
DEFAULT_STOP_PHRASES: dict[str, tuple[str, ...]] = {
    "en": ("stop", "halt", "freeze", "stop it", "stop stop"),
}
_PHRASE = re.compile(r"^[a-z]+(?:'[a-z]+)?(?: [a-z]+(?:'[a-z]+)?)*$")
MAX_PHRASES = 20
MAX_PHRASE_WORDS = 4


def known_languages() -> list[str]:
    return sorted(DEFAULT_STOP_PHRASES)


@dataclass(frozen=True)
class StopConfig:
    enabled: bool = field(default=True, metadata={"help": "spot stop phrases in every state"})
    language: str = field(default="en", metadata={"help": "language of the stop phrases"})
    phrases: tuple[str, ...] = field(
        default=(), metadata={"help": "stop phrases; empty = the language's defaults"}
    )
    reply_text: str = field(default="Stopping.", metadata={"help": "said when a stop is heard ('' = silent)"})
    refractory_ms: int = field(
        default=1000, metadata={"help": "a stop heard this soon after the last one is not acted on again"}
    )
    min_level_dbfs: float = field(
        default=-50.0, metadata={"help": "quieter frames are never speech (the idle room costs nothing)"}
    )
    onset_db: float = field(
        default=9.0, metadata={"help": "speech starts this far above the tracked noise floor"}
    )
    end_silence_ms: int = field(
        default=180, metadata={"help": "quiet that ends an utterance (adds to the latency)"}
    )
    end_drop_db: float = field(
        default=15.0,
        metadata={
            "help": "while the robot's voice is cancelled, end_silence_ms this far under an "
            "utterance's loudest is a pause where a clean stop is decided (its residual echo "
            "holds the utterance's end back)"
        },
    )
    max_utterance_ms: int = field(
        default=1800, metadata={"help": "longer speech is a sentence, not a stop, and is not decoded"}
    )
    max_other_words: int = field(
        default=1,
        metadata={
            "help": "words besides stop phrases and fillers an utterance may hold and still stop "
            "(recognition slips: a missed stop is worse than a spurious one); negations never"
        },
    )
    own_voice_window_ms: int = field(
        default=300,
        metadata={"help": "a stop heard within this of the robot's own stop-like word is its echo"},
    )
    cancel_echo: bool = field(
        default=True,
        metadata={
            "help": "echo_gate mode: cancel the robot's voice (aec engine, audio_played) before spotting"
        },
    )
    echo_memory: str = field(
        default="auto",
        metadata={
            "help": "file that keeps what the spotter's echo canceller learned across restarts, so a "
            "stop over the first reply after a start is heard: auto ($XDG_STATE_HOME/by_your_command/"
            "echo_path/<node>.stop_spotter.npz), none, or a path"
        },
    )

    def __post_init__(self) -> None:
        if not self.echo_memory.strip():
            raise ValueError("stop_echo_memory must be auto, none or a file path, got an empty string")
        if self.language not in DEFAULT_STOP_PHRASES:
            raise ValueError(
                f"stop_language {self.language!r} is not supported; known languages: {known_languages()}"
            )
        if len(self.phrases) > MAX_PHRASES:
            raise ValueError(f"stop_phrases: at most {MAX_PHRASES} phrases, got {len(self.phrases)}")
        for phrase in self.phrases:
            if not isinstance(phrase, str) or not _PHRASE.match(phrase):
                raise ValueError(
                    f"stop_phrases: {phrase!r} is not a phrase (lower-case words separated by one space)"
                )
            if len(phrase.split()) > MAX_PHRASE_WORDS:
                raise ValueError(f"stop_phrases: {phrase!r} has more than {MAX_PHRASE_WORDS} words")
        if len(self.reply_text) > 100:
            raise ValueError(f"stop_reply_text: at most 100 characters, got {len(self.reply_text)}")
        if not 0 <= self.refractory_ms <= 10_000:
            raise ValueError(f"stop_refractory_ms must be in [0, 10000], got {self.refractory_ms}")
        if not -90.0 <= self.min_level_dbfs <= -10.0:
            raise ValueError(f"stop_min_level_dbfs must be in [-90, -10], got {self.min_level_dbfs}")
        if not 3.0 <= self.onset_db <= 40.0:
            raise ValueError(f"stop_onset_db must be in [3, 40], got {self.onset_db}")
        if not 60 <= self.end_silence_ms <= 1000:
            raise ValueError(f"stop_end_silence_ms must be in [60, 1000], got {self.end_silence_ms}")
        if not 6.0 <= self.end_drop_db <= 60.0:  # also refuses NaN
            raise ValueError(f"stop_end_drop_db must be in [6, 60], got {self.end_drop_db}")
        if not 500 <= self.max_utterance_ms <= 5000:
            raise ValueError(f"stop_max_utterance_ms must be in [500, 5000], got {self.max_utterance_ms}")
        if not 0 <= self.max_other_words <= 3:
            raise ValueError(f"stop_max_other_words must be in [0, 3], got {self.max_other_words}")
        if not 0 <= self.own_voice_window_ms <= 2000:
            raise ValueError(f"stop_own_voice_window_ms must be in [0, 2000], got {self.own_voice_window_ms}")

    @property
    def stop_phrases(self) -> tuple[str, ...]:
        """The phrases spotted: the configured ones, else the language's defaults."""
        return self.phrases or DEFAULT_STOP_PHRASES[self.language]
