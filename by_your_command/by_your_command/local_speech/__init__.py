"""The offline speech engine: recognition of commands, the robot's tools' phrases, wake/sleep/stop
phrases and a few questions, and espeak-ng replies. No network, no keys; pure library (the agent
Provider wraps it)."""

from by_your_command.local_speech.recognizer import (
    OfflineRecognizer,
    Recognition,
    RecognizerConfig,
    Rejection,
    Search,
)
from by_your_command.local_speech.replies import NOT_CAUGHT, RepliesConfig, acknowledgement, answer
from by_your_command.local_speech.speaker import Speaker, SpeakerConfig, SpeechError
from by_your_command.local_speech.spoken import RecognitionKind, SpokenVocabularyConfig
from by_your_command.local_speech.tool_phrases import PhraseLimits, ToolPhrase, select_phrases

__all__ = [
    "NOT_CAUGHT",
    "PhraseLimits",
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
    "ToolPhrase",
    "acknowledgement",
    "answer",
    "select_phrases",
]
