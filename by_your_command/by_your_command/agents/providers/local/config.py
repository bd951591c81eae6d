"""The offline provider's settings (the `provider` section of config/agent_offline.yaml).

Flat and simple-typed, so app_providers.typed_settings can check every value from a file; the
engine's own configs (RecognizerConfig, SpeakerConfig, RepliesConfig) are built from it.
"""

from __future__ import annotations

from dataclasses import dataclass

from by_your_command.local_speech.replies import NOT_CAUGHT, RepliesConfig
from by_your_command.local_speech.speaker import SpeakerConfig
from by_your_command.local_speech.tool_phrases import PhraseLimits


@dataclass(frozen=True)
class OfflineConfig:
    voice: str = "en-us"  # espeak-ng voice
    words_per_minute: int = 165  # espeak-ng speaking rate
    min_confidence: float = 0.0  # a command or question below this posterior is treated as not caught
    commands_file: str = ""  # the command vocabulary; "" = the installed config/commands.yaml
    robot_name: str = RepliesConfig.robot_name  # "who are you"
    capabilities_text: str = RepliesConfig.capabilities  # "what can you do"
    # Said to chat and noise, unless the user already speaks again (it would talk over them and,
    # half duplex, cut them short); "" = say nothing.
    not_heard_text: str = NOT_CAUGHT
    refusal_text: str = "I can't do that: {reason}."  # {reason} is the command processor's
    acknowledgements: tuple[tuple[str, str], ...] = ()  # command base -> said when accepted ("Looking up")
    max_turn_s: float = 30.0  # audio beyond this in one turn is dropped (counted), never buffered
    max_text_chars: int = 200  # a longer typed prompt is not matched (counted)
    decode_timeout_s: float = 20.0  # one turn's decoding, in a thread
    speak_timeout_s: float = 10.0  # one reply's synthesis (espeak-ng is killed after it)
    audio_chunk_ms: int = 200  # reply audio is emitted in chunks of this length
    event_queue_size: int = 256  # events the runtime has not read yet; the worker waits beyond it
    # The robot's tools' spoken phrases the recognizer takes (more are left out, counted and
    # logged), and the words in one: each phrase is a form to search, and Moonshine scores forms of
    # at most 16 tokens.
    max_tool_phrases: int = 512
    max_tool_phrase_words: int = 8

    def __post_init__(self) -> None:
        if not self.robot_name.strip():
            raise ValueError("robot_name must not be empty")
        if not 0.0 <= self.min_confidence <= 1.0:
            raise ValueError(f"min_confidence must be within [0, 1], got {self.min_confidence}")
        for name in ("max_turn_s", "decode_timeout_s", "speak_timeout_s"):
            if not 0.0 < getattr(self, name) <= 600.0:
                raise ValueError(f"{name} must be within (0, 600]")
        if self.max_text_chars < 1 or self.event_queue_size < 1:
            raise ValueError("max_text_chars and event_queue_size must be >= 1")
        if not 10 <= self.audio_chunk_ms <= 2000:
            raise ValueError(f"audio_chunk_ms must be within [10, 2000], got {self.audio_chunk_ms}")
        PhraseLimits(self.max_tool_phrases, self.max_tool_phrase_words)  # its own checks
        self.speaker()  # its own checks (a voice name espeak-ng can take), at start, not at the first reply
        try:
            self.refusal_text.format(reason="r")
        except (KeyError, IndexError, ValueError):
            raise ValueError("refusal_text may use {reason} and no other field") from None

    def speaker(self) -> SpeakerConfig:
        return SpeakerConfig(
            voice=self.voice, words_per_minute=self.words_per_minute, timeout_s=self.speak_timeout_s
        )

    def replies(self) -> RepliesConfig:
        acknowledgements = {**RepliesConfig().acknowledgements, **dict(self.acknowledgements)}
        return RepliesConfig(self.robot_name, acknowledgements, self.capabilities_text)
