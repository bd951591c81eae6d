"""A GPT-Live client delegation → one of the robot's tools, by what the user said.

A client delegation names no function and carries no arguments: the task is the user's words
(gpt_live/events.py). Without a second model to read them, the words are matched against the tools'
declared phrases (tools.yaml `spoken:`, the ones the offline agent hears), whole: "go to the
kitchen", "please go to the kitchen". Only a whole match counts, after polite words at either end:
"don't go to the kitchen" contains the phrase but is not it, and motion needs positive evidence.
No match: the words go to the command processor as a `robot_command` (its grammar knows the spoken
commands), and whatever it says back, a verdict or a refusal, is the delegation's result.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from by_your_command.agents.provider import ToolSpec
from by_your_command.local_speech.tool_phrases import select_phrases, words_of

# Said around a request without changing it ("robot, could you please dock now, thanks").
_POLITE_OPENINGS = (
    "hey robot",
    "robot",
    "okay",
    "ok",
    "please",
    "could you",
    "can you",
    "would you",
    "will you",
)
_POLITE_CLOSINGS = ("please", "now", "thanks", "thank you", "for me")


@dataclass(frozen=True)
class DelegatedCall:
    tool: str
    arguments: str  # JSON object


def core_words(said: str) -> str:
    """The request without polite words at its ends (repeatedly: "robot please could you ...")."""
    words = words_of(said)
    changed = True
    while changed and words:
        changed = False
        for opening in _POLITE_OPENINGS:
            if words == opening or words.startswith(opening + " "):
                words, changed = words[len(opening) :].strip(), True
        for closing in _POLITE_CLOSINGS:
            if words == closing or words.endswith(" " + closing):
                words, changed = words[: -len(closing)].strip(), True
    return words


def match_tool(said: str, tools: Sequence[ToolSpec]) -> DelegatedCall | None:
    """The tool call whose declared phrase is exactly what was asked; None when none (or two) is."""
    declared = [(tool.name, phrase, arguments) for tool in tools for phrase, arguments in tool.spoken]
    if not declared:
        return None
    wanted = core_words(said)
    if not wanted:
        return None
    for phrase in select_phrases(declared).phrases:  # ambiguous phrases are left out there
        if phrase.words == wanted or core_words(phrase.words) == wanted:
            return DelegatedCall(phrase.tool, phrase.arguments)
    return None
