"""What the offline recognizer can hear: every spoken form, and what each one means.

Spoken forms are generated from the command vocabulary (config/commands.yaml), so a preset added
there can be said without touching this code. Each form maps to a canonical string: for commands
and phrases the normal form the command processor accepts (`pan@left`, `lookup`, `wake`), for
questions a short question id (`time`). Every command form is checked against CommandGrammar when
the set is built: a form whose canonical string does not parse back to itself is a bug, not a
runtime surprise.

Names that are not dictionary words are split into two that are (`leftish` -> "left ish",
`tenhut` -> "ten hut"); a word that cannot be pronounced is a configuration error.
"""

from __future__ import annotations

import dataclasses
import enum
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from by_your_command.commands.grammar import Command, CommandGrammar
from by_your_command.commands.vocabulary import CommandSpec, ModifierKind, ModifierUse, Vocabulary
from by_your_command.local_speech.tool_phrases import ToolPhrase
from by_your_command.vad.config import DEFAULT_SLEEP_PHRASES, DEFAULT_WAKE_PHRASES

_WORD = re.compile(r"^[a-z]+(?:'[a-z]+)?$")


class RecognitionKind(str, enum.Enum):
    COMMAND = "command"  # a robot command: canonical is its normal form (pan@left)
    PHRASE = "phrase"  # wake / sleep / stop: canonical is that command (they are gated separately)
    QUESTION = "question"  # a question the offline agent answers: canonical is its id (time)
    # A phrase of one of the robot's tools ("go to the kitchen"): canonical is the call,
    # `go_to {"place": "kitchen"}` (tool_phrases.ToolPhrase). Judged like a command.
    TOOL = "tool"
    REJECTED = "rejected"  # chat, noise, or nothing the grammar covers


@dataclass(frozen=True)
class SpokenForm:
    words: str  # lower-case dictionary words separated by single spaces
    kind: RecognitionKind
    canonical: str
    # A command form wrapped in a polite opening or closing: how many words they add ("can you
    # look up please": 3); 0 for a plain form.
    polite_words: int = 0
    extra: bool = False  # from extra_forms or extra_questions (SpokenVocabularyConfig), or polite of one

    @property
    def polite(self) -> bool:
        return self.polite_words > 0


def _default_phrases() -> dict[str, tuple[str, ...]]:
    return {
        "wake": tuple(DEFAULT_WAKE_PHRASES),
        "sleep": tuple(DEFAULT_SLEEP_PHRASES),
        # Stopping is the harmless mistake, so stop takes what people say when they mean it.
        "stop": ("stop", "stop moving", "halt", "freeze", "stop it", "stop now", "stop right now")
        + ("stop right there", "please stop", "stop please"),
    }


@dataclass(frozen=True)
class SpokenVocabularyConfig:
    # Extra ways to say a command or bearing name (the name itself is always a spoken form).
    aliases: dict[str, tuple[str, ...]] = field(
        default_factory=lambda: {
            "lookup": ("look up",),
            "lookout": ("look out",),
            "tenhut": ("attention",),
            "forward": ("ahead", "forwards"),
            "back": ("backward", "backwards"),
        }
    )
    # Whole forms that no name and bearing make, canonical command -> forms.
    extra_forms: dict[str, tuple[str, ...]] = field(default_factory=lambda: {"turn@back": ("turn around",)})
    # Canonical command -> phrases. These commands come back as PHRASE, so a sleeping robot can
    # listen for "wake" alone and "stop" can skip the queue.
    phrases: dict[str, tuple[str, ...]] = field(default_factory=_default_phrases)
    # Question id -> ways to ask it; the agent owns the answers.
    questions: dict[str, tuple[str, ...]] = field(
        default_factory=lambda: {
            "time": ("what time is it", "what is the time", "tell me the time"),
            "capabilities": ("what can you do", "help"),
            "identity": ("who are you", "what is your name"),
        }
    )
    # Ways to ask that Moonshine alone scores, like the extra forms. Without "... now", Moonshine's
    # word-for-word "What time is it now?" paid the end regret for "now" and was turned away; in
    # pocketsphinx's grammar, which must name some form, the form took "what time does it open".
    extra_questions: dict[str, tuple[str, ...]] = field(
        default_factory=lambda: {"time": ("what time is it now",)}
    )
    # Labels that label commands (follow, track) can take by voice: "follow me" -> follow@me.
    labels: tuple[str, ...] = ("me", "person", "ball")
    # Also accept "turn to the left" besides "turn left", for these bearings ("to the ahead" is
    # not English).
    direction_prefix: str = "to the"
    prefixed_bearings: tuple[str, ...] = (
        "left",
        "right",
        "full-left",
        "full-right",
        "back-left",
        "back-right",
    )
    # A lone bearing ("right") means pan@right in the command grammar, but spoken alone it is far
    # more often agreement than a command, so it is off unless asked for.
    bare_bearings: bool = False
    # People ask robots politely: every command may also be said after an opening and/or before a
    # closing ("please look up", "can you pan left please"). Not phrases: wake, sleep and stop
    # stay the short exact words their stricter accept rules are built for.
    polite_openings: tuple[str, ...] = ("please", "can you", "could you")
    polite_closings: tuple[str, ...] = ("please",)


def _spoken_name(name: str, aliases: dict[str, tuple[str, ...]]) -> tuple[str, ...]:
    plain = " ".join(name.replace("-", " ").replace("_", " ").split())
    return (plain, *aliases.get(name, ()))


def _direction_words(vocabulary: Vocabulary, config: SpokenVocabularyConfig) -> list[tuple[str, str]]:
    """(spoken, bearing) pairs for every bearing, with and without the direction prefix."""
    pairs = []
    for bearing in vocabulary.bearings:
        prefixed = config.direction_prefix and bearing in config.prefixed_bearings
        prefixes = ["", config.direction_prefix] if prefixed else [""]
        for spoken in _spoken_name(bearing, config.aliases):
            pairs += [(f"{prefix} {spoken}".strip(), bearing) for prefix in prefixes]
    return pairs


def _command_forms(
    spec: CommandSpec, vocabulary: Vocabulary, config: SpokenVocabularyConfig
) -> Iterable[tuple[str, str]]:
    names = _spoken_name(spec.name, config.aliases)
    if spec.modifier is not ModifierUse.REQUIRED:
        yield from ((name, spec.name) for name in names)
    if spec.modifier is ModifierUse.NONE:
        return
    if spec.modifier_kind is ModifierKind.LABEL:
        for name in names:
            for label in config.labels:
                yield f"{name} {label}", f"{spec.name}@{label}"
                if label != "me":
                    yield f"{name} the {label}", f"{spec.name}@{label}"
        return
    for name in names:
        for spoken, bearing in _direction_words(vocabulary, config):
            yield f"{name} {spoken}", f"{spec.name}@{bearing}"


def build_spoken_forms(
    vocabulary: Vocabulary, config: SpokenVocabularyConfig, tools: Iterable[ToolPhrase] = ()
) -> list[SpokenForm]:
    """Every spoken form, in a stable order; raises ValueError on a form of the vocabulary that maps
    ambiguously. A tool phrase (and its polite forms) never displaces a form of the vocabulary:
    one that is already said for something else is left out here (the caller names it)."""
    grammar = CommandGrammar(vocabulary)
    forms: dict[str, SpokenForm] = {}

    def add(
        words: str, kind: RecognitionKind, canonical: str, polite_words: int = 0, extra: bool = False
    ) -> None:
        words = " ".join(words.lower().split())
        known = forms.get(words)
        if known is not None and known.canonical != canonical:
            if kind is RecognitionKind.TOOL:
                return
            if known.kind is RecognitionKind.TOOL:  # the vocabulary's meaning wins ("can you stop")
                del forms[words]
            else:
                raise ValueError(f"spoken form {words!r} means both {known.canonical!r} and {canonical!r}")
        forms.setdefault(words, SpokenForm(words, kind, canonical, polite_words, extra))

    for canonical, spoken in config.phrases.items():
        _check_canonical(grammar, canonical)
        for words in spoken:
            add(words, RecognitionKind.PHRASE, canonical)
    for spec in vocabulary.commands.values():
        kind = _kind(spec.name, config)
        for words, canonical in _command_forms(spec, vocabulary, config):
            _check_canonical(grammar, canonical)
            add(words, kind, canonical)
    for canonical, spoken in config.extra_forms.items():
        kind = _kind(_check_canonical(grammar, canonical).base, config)
        for words in spoken:
            add(words, kind, canonical, extra=True)
    if config.bare_bearings and "pan" in vocabulary.commands:
        for words, bearing in _direction_words(vocabulary, config):
            _check_canonical(grammar, f"pan@{bearing}")
            add(words, RecognitionKind.COMMAND, f"pan@{bearing}")
    for question, spoken in config.questions.items():
        for words in spoken:
            add(words, RecognitionKind.QUESTION, question)
    for question, spoken in config.extra_questions.items():
        if question not in config.questions:
            raise ValueError(f"extra question {question!r} is not one of the questions")
        for words in spoken:
            add(words, RecognitionKind.QUESTION, question, extra=True)
    for phrase in tools:
        add(phrase.words, RecognitionKind.TOOL, phrase.canonical)
    commands = [
        form for form in forms.values() if form.kind in (RecognitionKind.COMMAND, RecognitionKind.TOOL)
    ]
    for opening, closing in _politeness(config):
        for form in commands:
            polite_words = len(f"{opening} {closing}".split())
            add(f"{opening} {form.words} {closing}", form.kind, form.canonical, polite_words, form.extra)
    return list(forms.values())


def _kind(command: str, config: SpokenVocabularyConfig) -> RecognitionKind:
    """PHRASE for the commands said as wake/sleep/stop phrases, COMMAND for the others."""
    return RecognitionKind.PHRASE if command in config.phrases else RecognitionKind.COMMAND


def _politeness(config: SpokenVocabularyConfig) -> list[tuple[str, str]]:
    """(opening, closing) pairs that wrap a command: at least one, and not the same twice ("please
    ... please")."""
    openings, closings = ("", *config.polite_openings), ("", *config.polite_closings)
    return [(o, c) for o in openings for c in closings if (o or c) and o != c]


def _check_canonical(grammar: CommandGrammar, canonical: str) -> Command:
    """The command `canonical` is; raises ValueError unless it is one in normal form."""
    parsed = grammar.parse_one(canonical)
    if parsed.command is None or parsed.command.text != canonical:
        raise ValueError(f"{canonical!r} is not a command in normal form: {parsed.reason or parsed.command}")
    return parsed.command


def pronounceable(forms: list[SpokenForm], in_dictionary: Callable[[str], bool]) -> list[SpokenForm]:
    """The forms rewritten into dictionary words: a missing word is split in two that exist.

    Raises ValueError naming the word when neither the word nor any split of it is known.
    """
    cache: dict[str, str] = {}

    def word(text: str) -> str:
        if text not in cache:
            cache[text] = _pronounceable_word(text, in_dictionary)
        return cache[text]

    return [
        dataclasses.replace(form, words=" ".join(word(part) for part in form.words.split())) for form in forms
    ]


def _pronounceable_word(text: str, in_dictionary: Callable[[str], bool]) -> str:
    if not _WORD.match(text):
        raise ValueError(f"{text!r} is not a plain word (letters and one apostrophe)")
    if in_dictionary(text):
        return text
    # The longest known head first: "leftish" -> "left ish", not "le ftish".
    for cut in range(len(text) - 2, 1, -1):
        head, tail = text[:cut], text[cut:]
        if in_dictionary(head) and in_dictionary(tail):
            return f"{head} {tail}"
    raise ValueError(f"cannot pronounce {text!r}: not in the dictionary and not two words that are")


_DIGITS = {
    "zero": "0", "one": "1", "two": "2", "three": "3", "four": "4", "five": "5",
    "six": "6", "seven": "7", "eight": "8", "nine": "9", "ten": "10",
}  # fmt: skip


def written_forms(name_words: str, spoken_words: str) -> tuple[str, ...]:
    """The ways a transcriber may write one spoken form, first the spoken words themselves.

    `name_words` is the form as generated from the vocabulary ("bumper leftish", "tenhut"),
    `spoken_words` as made pronounceable ("bumper left ish", "ten hut"). A transcriber writes
    what it hears as ordinary text: a split name as one word, hyphenated or apart ("leftish",
    "left-ish", "left ish"), and number words often as digits ("10 hut").
    """
    names, spoken = name_words.split(), spoken_words.split()
    choices: list[list[str]] = []
    position = 0
    for name in names:
        parts = [name]
        while "".join(parts[1:]) != name and position < len(spoken):  # its pronounceable words
            parts.append(spoken[position])
            position += 1
        pieces = parts[1:]
        if "".join(pieces) != name:
            raise ValueError(f"{spoken_words!r} is not {name_words!r} made pronounceable")
        ways = [" ".join(pieces)]
        if len(pieces) > 1:
            ways += ["-".join(pieces), name]
        digits = [_DIGITS.get(piece, piece) for piece in pieces]
        if digits != pieces:
            ways += [" ".join(digits)] + (["-".join(digits)] if len(pieces) > 1 else [])
        choices.append(ways)
    if position != len(spoken):
        raise ValueError(f"{spoken_words!r} is not {name_words!r} made pronounceable")
    forms = [""]
    for ways in choices:
        forms = [f"{head} {way}".strip() for head in forms for way in ways]
    return tuple(dict.fromkeys(forms))


# How a phrase said again is written: "Stop stop", "Stop, stop", "Stop. Stop. Stop.", "Stop! Stop!";
# True where the next one starts a sentence.
_REPEAT_SEPARATORS = ((" ", False), (", ", False), (". ", True), ("! ", True))


def sentence_case(text: str) -> str:
    """A capital first letter, the rest as it is ("look up" -> "Look up"): how a transcriber
    starts a sentence."""
    return text[:1].upper() + text[1:]


def said_again(ways: tuple[str, ...], times: int = 3) -> tuple[str, ...]:
    """The ways of writing a phrase, each also said up to `times` times over ("stop, stop!"): a
    person who wants the robot to stop says it again, and a form that ended after the first "stop"
    would pay the end regret for the rest and be turned away."""
    repeated = []
    for way in ways:
        for separator, sentence in _REPEAT_SEPARATORS:
            again = sentence_case(way) if sentence else way
            repeated += [separator.join([way] + [again] * (count - 1)) for count in range(2, times + 1)]
    return tuple(dict.fromkeys([*ways, *repeated]))
