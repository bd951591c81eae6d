"""Whether what Moonshine wrote asks for a command or only holds its words: "I turned left" and
"she looks up" tell of the action, "don't look up" forbids it, "if you turn left" makes it a
condition.

Such a sentence holds the form's words, so both models score the form close behind what was said
(a short word and the verb's ending are all that differ: "I followed the ball" is "follow the ball"
at regret 5-7 to Moonshine, and pocketsphinx's grammar pass, which knows only the forms, hears the
form). Regret alone cannot turn it away without turning away noisy commands too. What Moonshine
wrote can: a command says its verb bare, with no subject before it, no negation and no condition,
unless the form holds the word ("can you turn left").

Each word list is what Moonshine does not write for a command said plainly (measured on the
benchmark's commands, bench/offline_experiments.md): not "when", "after", "before" (espeak's
"backward" is "back when" to it, "look up to the right" "look after the ride"), not "not"
("attention ahead" in noise: "a fan should not add"); a subject only before a verb ("I'm
right." is "pan right" misheard), and in noise "you" or "we" only before a verb with an ending
(noise before a command makes it start "You look out right."). A past tense before a form word
that starts with t or d is no evidence either: "reach to the left" is "reached on the left" to it.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, field

# "it" is an object as often as a subject ("stop it", "look it up").
SUBJECTS = frozenset(
    ("i", "i'm", "i've", "i'd", "i'll", "he", "he's", "she", "she's", "it's", "they", "they're", "they've")
    + ("we", "we're", "we've", "you", "you're", "you've")
)
NOISE_SUBJECTS = frozenset(("we", "you"))  # written before noisy commands, with the verb bare
NEGATIONS = frozenset(
    ("don't", "never", "didn't", "doesn't", "won't", "can't", "cannot", "shouldn't", "mustn't", "wouldn't")
    + ("couldn't", "isn't", "aren't", "wasn't", "weren't", "haven't", "hasn't")
)
CONDITIONS = frozenset(("if", "unless"))
# Past tenses a suffix rule cannot make.
IRREGULAR = {
    "wake": ("woke", "woken"),
    "sleep": ("slept",),
    "freeze": ("froze", "frozen"),
    "go": ("went", "gone"),
}


def inflections(word: str) -> set[str]:
    """The word with an ending: turn -> turns, turned, turning; move -> moved, moving; stop ->
    stopped, stopping; reach -> reaches; and the irregular past tenses of the vocabulary's verbs."""
    endings = {word + "s", word + "es", word + "ed", word + "d", word + "ing"}
    if word.endswith("e"):
        endings.add(word[:-1] + "ing")
    if len(word) >= 3 and word[-1] not in "aeiouwxy" and word[-2] in "aeiou" and word[-3] not in "aeiou":
        endings |= {word + word[-1] + "ed", word + word[-1] + "ing"}  # stop -> stopped, pan -> panned
    endings.update(IRREGULAR.get(word, ()))
    endings.discard(word)
    return endings


@dataclass(frozen=True)
class Verbs:
    """The vocabulary's verbs (its forms' first words), bare and with every ending."""

    bare: frozenset[str]
    inflected: frozenset[str] = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "inflected", frozenset(e for verb in self.bare for e in inflections(verb)))


def not_asked_for(
    written: Sequence[str],
    form: Sequence[str],
    verbs: Verbs,
    same_meaning: Collection[str],
    noisy: bool = False,
) -> bool:
    """Whether the transcript's words (lower case) do not ask for the form (its words in order):
    a negation or condition the form does not hold; one of the form's verbs with an ending
    ("turned", "moving") that no form of the same meaning says ("moving": "stop moving"); or
    a subject the form does not hold right before one of the vocabulary's `verbs`, bare or with
    an ending ("I look up", "she woke up"; in noise "we" and "you" only before an ending)."""
    endings: set[str] = set()
    for place, word in enumerate(form):
        if word not in verbs.bare:  # "pleased", "balls": no one tells of an action by them
            continue
        merged = place + 1 < len(form) and form[place + 1][:1] in "td"  # "reach to" sounds "reached"
        endings |= {ending for ending in inflections(word) if not (merged and ending.endswith("d"))}
    endings -= set(same_meaning)
    for place, word in enumerate(written):
        if word in form:
            continue
        if word in NEGATIONS or word in CONDITIONS or word in endings:
            return True
        following = written[place + 1] if place + 1 < len(written) else ""
        if word in SUBJECTS and (
            following in verbs.inflected
            or (following in verbs.bare and not (noisy and word in NOISE_SUBJECTS))
        ):
            return True
    return False
