"""The offline speech engine: pocketsphinx recognition of commands, phrases and a few questions,
and espeak-ng replies. No network, no keys; pure library (the agent Provider wraps it)."""

from by_your_command.offline.recognizer import (
    OfflineRecognizer,
    Recognition,
    RecognizerConfig,
    Rejection,
    Search,
)
from by_your_command.offline.replies import NOT_CAUGHT, RepliesConfig, acknowledgement, answer
from by_your_command.offline.speaker import Speaker, SpeakerConfig, SpeechError
from by_your_command.offline.spoken import RecognitionKind, SpokenVocabularyConfig

__all__ = [
    "NOT_CAUGHT",
    "OfflineRecognizer",
    "Recognition",
    "RecognitionKind",
    "RecognizerConfig",
    "Rejection",
    "RepliesConfig",
    "Search",
    "Speaker",
    "SpeakerConfig",
    "SpeechError",
    "SpokenVocabularyConfig",
    "acknowledgement",
    "answer",
]
