"""The robot's tools' spoken phrases in the offline recognizer: selected and bounded, heard like
commands on synthesized speech, and chat with a tool's words in it still rejected."""

from __future__ import annotations

import logging
from collections.abc import Callable

import pytest

from by_your_command.commands.vocabulary import load_vocabulary
from by_your_command.local_speech.moonshine import FormScore
from by_your_command.local_speech.recognizer import Evidence, OfflineRecognizer
from by_your_command.local_speech.rescoring import Alignment, Candidate
from by_your_command.local_speech.spoken import RecognitionKind, SpokenVocabularyConfig, build_spoken_forms
from by_your_command.local_speech.tool_phrases import (
    AMBIGUOUS,
    BAD_TOOL,
    NOT_IN_DICTIONARY,
    NOT_WORDS,
    TAKEN,
    TOO_LONG,
    TOO_MANY,
    PhraseLimits,
    ToolPhrase,
    select_phrases,
    tool_call,
)

pytestmark = pytest.mark.unit
RATE = 16000
Synthesize = Callable[[str, str], bytes]
PLACES = ("kitchen", "charging dock", "living room")
DECLARED = [
    *(
        ("go_to", f"{verb} to the {place}", f'{{"place": "{place}"}}')
        for place in PLACES
        for verb in ("go", "drive")
    ),
    ("dock", "dock", "{}"),
    ("report", "report your battery", '{"what": "battery", "detail": false}'),
]


@pytest.fixture(scope="module")
def hearing(recognizer: OfflineRecognizer) -> OfflineRecognizer:
    """The module's recognizer with the tools' phrases (a rebuild: the models are shared)."""
    return recognizer.with_tools(select_phrases(DECLARED).phrases)


# --- selection ---------------------------------------------------------------------------------


def test_phrases_are_normalised_and_their_arguments_made_canonical() -> None:
    selection = select_phrases(
        [
            ("go_to", "  Go to the Living-Room! ", '{"place":"living room"}'),
            ("report", "report", '{"b": 1, "a": 2}'),
        ]
    )
    assert selection.phrases == (
        ToolPhrase("go to the living room", "go_to", '{"place": "living room"}'),
        ToolPhrase("report", "report", '{"a": 2, "b": 1}'),
    )
    assert tool_call(selection.phrases[0].canonical) == ("go_to", '{"place": "living room"}')
    assert not selection.cut


def test_what_cannot_be_a_phrase_is_left_out_counted_and_named(caplog: pytest.LogCaptureFixture) -> None:
    declared = [
        ("go_to", "go to the kitchen", '{"place": "kitchen"}'),
        ("go_to", "go to room 3", '{"place": "room 3"}'),  # a digit: not a plain word
        ("go_to", "", "{}"),
        ("go_to", "go " * 9, "{}"),  # more words than max_words
        ("go_to", "x" * 500, "{}"),  # absurdly long
        ("go_to", "go home", "[1]"),  # arguments not an object
        ("go_to", "go away", '{"a": "' + "x" * 2000 + '"}'),
        ("bad name!", "wave", "{}"),
        ("wave", "hello robot", "{}"),
        ("greet", "hello robot", '{"loud": true}'),  # one phrase, two calls: neither
        ("go_to", "go to the kitchen", '{"place": "kitchen"}'),  # the same again: kept once
    ]
    with caplog.at_level(logging.WARNING):
        selection = select_phrases(declared)
    assert [phrase.words for phrase in selection.phrases] == ["go to the kitchen"]
    assert selection.cut == {NOT_WORDS: 2, TOO_LONG: 2, BAD_TOOL: 3, AMBIGUOUS: 1}
    assert "go to room 3" in caplog.text and "hello robot" in caplog.text


def test_at_most_max_phrases_are_kept_and_the_rest_counted(caplog: pytest.LogCaptureFixture) -> None:
    words = ["alpha", "bravo", "charlie", "delta", "echo", "foxtrot", "golf", "hotel", "india", "juliet"]
    declared = [("fetch", f"fetch the {word} box", "{}") for word in words]
    with caplog.at_level(logging.WARNING):
        selection = select_phrases(declared, PhraseLimits(max_phrases=3, max_words=4))
    assert [phrase.words for phrase in selection.phrases] == [f"fetch the {w} box" for w in words[:3]]
    assert selection.cut == {TOO_MANY: 7}
    assert "7 tool phrase(s) left out (too many phrases)" in caplog.text
    with pytest.raises(ValueError):
        PhraseLimits(max_phrases=0)


def test_a_tool_phrase_never_displaces_a_command_and_gets_the_polite_forms_commands_get() -> None:
    phrases = [ToolPhrase("go to the kitchen", "go_to", "{}"), ToolPhrase("look up", "lookup_tool", "{}")]
    forms = {
        form.words: form for form in build_spoken_forms(load_vocabulary(), SpokenVocabularyConfig(), phrases)
    }
    assert (forms["look up"].kind, forms["look up"].canonical) == (RecognitionKind.COMMAND, "lookup")
    for said in ("go to the kitchen", "please go to the kitchen", "can you go to the kitchen please"):
        assert (forms[said].kind, forms[said].canonical) == (RecognitionKind.TOOL, "go_to {}")


# --- the recognizer ------------------------------------------------------------------------------


def test_the_recognizer_leaves_out_what_it_cannot_say_or_what_is_a_command_and_names_it(
    recognizer: OfflineRecognizer, caplog: pytest.LogCaptureFixture
) -> None:
    phrases = [
        ToolPhrase("go to the kitchen", "go_to", "{}"),
        ToolPhrase("frobnicate the qwzx", "frob", "{}"),  # not in the dictionary, nor two words that are
        ToolPhrase("stop", "halt_tool", "{}"),  # the stop phrase stays the stop phrase
    ]
    with caplog.at_level(logging.WARNING):
        rebuilt = recognizer.with_tools(phrases)
    assert [phrase.words for phrase in rebuilt.tools] == ["go to the kitchen"]
    assert rebuilt.tools_left_out == {NOT_IN_DICTIONARY: 1, TAKEN: 1}
    assert "frobnicate the qwzx" in caplog.text and "'stop'" in caplog.text
    assert {form.canonical for form in rebuilt.tool_forms} == {"go_to {}"}
    # The recognizer it was built from is left as it was: no tool forms.
    assert recognizer.tools == () and not any(f.kind is RecognitionKind.TOOL for f in recognizer.forms)
    assert rebuilt._decoder.lookup_word("kitchen") is not None
    assert recognizer._decoder.lookup_word("kitchen") is None


@pytest.mark.parametrize(
    ("text", "voice", "call"),
    [
        ("go to the kitchen", "en-us+m7", ("go_to", '{"place": "kitchen"}')),
        ("drive to the charging dock", "en-gb-x-rp", ("go_to", '{"place": "charging dock"}')),
        ("please go to the living room", "en-us+f3", ("go_to", '{"place": "living room"}')),
        ("report your battery", "en-us+m7", ("report", '{"detail": false, "what": "battery"}')),
    ],
)
def test_a_spoken_tool_phrase_is_that_tools_call(
    hearing: OfflineRecognizer, synthesize: Synthesize, text: str, voice: str, call: tuple[str, str]
) -> None:
    result = hearing.recognize(synthesize(text, voice), RATE)
    assert result.kind is RecognitionKind.TOOL, result
    assert tool_call(result.canonical) == call


def test_commands_are_heard_as_before_beside_the_tools(
    hearing: OfflineRecognizer, synthesize: Synthesize
) -> None:
    result = hearing.recognize(synthesize("look up", "en-us+m7"), RATE)
    assert (result.kind, result.canonical) == (RecognitionKind.COMMAND, "lookup")


@pytest.mark.parametrize(
    ("text", "voice"),
    [
        ("the kitchen is nice", "en-us+m7"),
        ("I docked my boat", "en-gb-x-rp"),
        ("the living room needs painting", "en-us+f3"),
        ("my battery is almost empty", "en-us+m7"),
        ("go to the kitchen and make some tea", "en-029"),  # a phrase that goes on
    ],
)
def test_chat_with_a_tools_words_is_rejected(
    hearing: OfflineRecognizer, synthesize: Synthesize, text: str, voice: str
) -> None:
    result = hearing.recognize(synthesize(text, voice), RATE)
    assert result.kind is RecognitionKind.REJECTED, result


def test_a_tool_phrase_needs_positive_evidence_like_a_command_that_moves_the_base(
    hearing: OfflineRecognizer,
) -> None:
    """Nothing says which tool drives the robot: a tool phrase is taken on the reranking only when
    Moonshine wrote one of its words that carries meaning ("the" is none) or pocketsphinx's
    grammar heard it (recorded evidence, decided without decoding)."""
    forms = {form.words: index for index, form in enumerate(hearing.forms)}
    kitchen, bumper = forms["go to the kitchen"], forms["bumper"]
    acceptance = hearing.config.acceptance
    noisy = acceptance.noisy_below_snr_db - 8.0

    def decided(free_text: str, grammar_text: str) -> str:
        grammar = next((f for f in hearing.forms if f.words == grammar_text), None)
        taken, other = FormScore(kitchen, -6.0, 5.0), FormScore(bumper, -8.0, 6.0)
        candidates = [
            Candidate(
                taken, Alignment(-90.0, 100), 4, grammar is not None and grammar.words == "go to the kitchen"
            ),
            Candidate(other, Alignment(-180.0, 100), 1, grammar is not None and grammar.words == "bumper"),
        ]
        evidence = Evidence(noisy, [taken, other], free_text, grammar_text, candidates)
        chosen = hearing.decide(evidence, acceptance, lambda: "")
        return "" if chosen is None else hearing.forms[chosen.index].canonical

    go_to = 'go_to {"place": "kitchen"}'
    assert decided("", "bumper") == ""
    assert decided("The.", "bumper") == ""  # a word without meaning is no evidence
    assert decided("", "go to the kitchen") == go_to  # pocketsphinx's grammar heard it
    assert decided("Kitchens.", "bumper") == ""  # not one of its words
    assert decided("Go to the kitten.", "bumper") == go_to  # Moonshine wrote words of it
