"""Spoken forms generated from the command vocabulary: coverage and the round trip to commands."""

from __future__ import annotations

import dataclasses

import pytest

from by_your_command.commands.grammar import CommandGrammar
from by_your_command.commands.vocabulary import ModifierKind, ModifierUse, load_vocabulary
from by_your_command.local_speech.language_model import GarbageWeights, arpa_model, jsgf_grammar
from by_your_command.local_speech.spoken import (
    RecognitionKind,
    SpokenVocabularyConfig,
    build_spoken_forms,
    pronounceable,
    said_again,
    written_forms,
)

VOCABULARY = load_vocabulary()
CONFIG = SpokenVocabularyConfig()
FORMS = build_spoken_forms(VOCABULARY, CONFIG)
DICTIONARY = {"turn", "left", "ish", "ten", "hut", "look", "up"}


@pytest.mark.unit
def test_every_command_and_modifier_of_the_vocabulary_can_be_said() -> None:
    canonicals = {form.canonical for form in FORMS}
    for spec in VOCABULARY.commands.values():
        if spec.modifier is not ModifierUse.REQUIRED:
            assert spec.name in canonicals
        if spec.modifier is ModifierUse.NONE:
            continue
        modifiers = CONFIG.labels if spec.modifier_kind is ModifierKind.LABEL else VOCABULARY.bearings
        for modifier in modifiers:
            assert f"{spec.name}@{modifier}" in canonicals


@pytest.mark.unit
def test_every_command_form_round_trips_to_the_normal_form_the_processor_accepts() -> None:
    grammar = CommandGrammar(VOCABULARY)
    commands = [form for form in FORMS if form.kind is not RecognitionKind.QUESTION]
    assert len(commands) > 100
    for form in commands:
        parsed = grammar.parse_one(form.canonical)
        assert parsed.command is not None and parsed.command.text == form.canonical, form


@pytest.mark.unit
def test_natural_spoken_forms_map_to_canonical_commands() -> None:
    meaning = {form.words: (form.kind, form.canonical) for form in FORMS}
    assert meaning["look up"] == (RecognitionKind.COMMAND, "lookup")
    assert meaning["pan left"] == (RecognitionKind.COMMAND, "pan@left")
    assert meaning["turn to the full right"] == (RecognitionKind.COMMAND, "turn@full-right")
    assert meaning["move ahead"] == (RecognitionKind.COMMAND, "move@forward")
    assert meaning["follow me"] == (RecognitionKind.COMMAND, "follow@me")
    assert meaning["go to sleep"] == (RecognitionKind.PHRASE, "sleep")
    assert meaning["wake up"] == (RecognitionKind.PHRASE, "wake")
    assert meaning["stop"] == (RecognitionKind.PHRASE, "stop")
    for words in ("stop it", "please stop", "stop please", "stop right there"):
        assert meaning[words] == (RecognitionKind.PHRASE, "stop"), words
    assert meaning["what time is it"] == (RecognitionKind.QUESTION, "time")


@pytest.mark.unit
def test_backward_forwards_and_turn_around_are_said_as_people_say_them() -> None:
    meaning = {form.words: form for form in FORMS}
    assert meaning["move backward"].canonical == "move@back"
    assert meaning["reach backwards"].canonical == "reach@back"
    assert meaning["turn forwards"].canonical == "turn@forward"
    assert meaning["turn around"].canonical == "turn@back"
    assert meaning["turn around"].kind is RecognitionKind.COMMAND
    assert meaning["turn around"].extra and not meaning["turn back"].extra
    assert meaning["please turn around"].polite and meaning["please turn around"].extra
    # Only the bearing "back" takes them: "backward left" is no form.
    assert "move backward left" not in meaning
    plain = build_spoken_forms(VOCABULARY, SpokenVocabularyConfig(aliases={}, extra_forms={}))
    assert not {"move backward", "turn around", "move ahead"} & {form.words for form in plain}


@pytest.mark.unit
def test_an_extra_form_must_be_a_command_in_normal_form() -> None:
    with pytest.raises(ValueError, match="normal form"):
        build_spoken_forms(VOCABULARY, SpokenVocabularyConfig(extra_forms={"turn@around": ("turn around",)}))
    clash = SpokenVocabularyConfig(extra_forms={"turn@left": ("turn right",)})
    with pytest.raises(ValueError, match="means both"):
        build_spoken_forms(VOCABULARY, clash)


@pytest.mark.unit
def test_an_extra_question_is_moonshines_alone_and_must_be_a_question() -> None:
    meaning = {form.words: form for form in FORMS}
    now = meaning["what time is it now"]
    assert (now.kind, now.canonical, now.extra) == (RecognitionKind.QUESTION, "time", True)
    assert not meaning["what time is it"].extra
    unknown = SpokenVocabularyConfig(extra_questions={"weather": ("is it raining",)})
    with pytest.raises(ValueError, match="not one of the questions"):
        build_spoken_forms(VOCABULARY, unknown)


@pytest.mark.unit
def test_commands_can_be_asked_for_politely_phrases_and_questions_cannot() -> None:
    meaning = {form.words: form for form in FORMS}
    # The polite form and how many of its words are politeness.
    polite = {
        "please look up": 1,
        "can you pan left": 2,
        "could you turn to the left please": 3,
        "move ahead please": 1,
    }
    for words, politeness in polite.items():
        assert meaning[words].kind is RecognitionKind.COMMAND and meaning[words].polite, words
        assert meaning[words].polite_words == politeness, words
    assert meaning["can you pan left"].canonical == "pan@left"
    assert not meaning["pan left"].polite and meaning["pan left"].polite_words == 0
    for words in ("can you wake up", "go to sleep please", "please what time is it"):
        assert words not in meaning
    assert not meaning["please stop"].polite  # a stop phrase of its own, not a wrapped command
    assert "please look up please" not in meaning
    plain = [form for form in FORMS if form.kind is RecognitionKind.COMMAND and not form.polite]
    assert sum(form.polite for form in FORMS) == 6 * len(plain)  # 3 openings x (none or "please") + "please"
    strict = build_spoken_forms(VOCABULARY, SpokenVocabularyConfig(polite_openings=(), polite_closings=()))
    assert not any(form.polite for form in strict) and len(strict) == len(FORMS) - 6 * len(plain)


@pytest.mark.unit
def test_a_lone_bearing_is_a_command_only_when_asked_for() -> None:
    assert "right" not in {form.words for form in FORMS}
    with_bearings = build_spoken_forms(VOCABULARY, dataclasses.replace(CONFIG, bare_bearings=True))
    assert {form.words: form.canonical for form in with_bearings}["right"] == "pan@right"


@pytest.mark.unit
def test_a_spoken_form_with_two_meanings_or_a_bad_phrase_is_a_configuration_error() -> None:
    clash = dataclasses.replace(CONFIG, questions={"time": ("stop",)})
    with pytest.raises(ValueError, match="means both"):
        build_spoken_forms(VOCABULARY, clash)
    bad_phrase = dataclasses.replace(CONFIG, phrases={"dance": ("dance",)})
    with pytest.raises(ValueError, match="not a command"):
        build_spoken_forms(VOCABULARY, bad_phrase)


@pytest.mark.unit
def test_names_outside_the_dictionary_are_split_into_words_that_are_in_it() -> None:
    forms = [f for f in FORMS if f.words in ("turn leftish", "tenhut", "look up")]
    spoken = pronounceable(forms, DICTIONARY.__contains__)
    assert {form.words for form in spoken} == {"turn left ish", "ten hut", "look up"}
    with pytest.raises(ValueError, match="cannot pronounce 'zqxj'"):
        pronounceable([dataclasses.replace(forms[0], words="zqxj")], DICTIONARY.__contains__)


@pytest.mark.unit
def test_the_model_chains_each_form_and_lets_any_word_loop_as_garbage() -> None:
    text = arpa_model(["look up", "stop"], ["hello", "world"], GarbageWeights())
    assert "ngram 1=7" in text  # <s> </s> look up stop hello world
    assert "-0.3233 <s> look" in text and "-0.3233 <s> stop" in text  # (1 - 0.05) / 2
    assert "-0.0044 look up" in text and "-0.0044 up </s>" in text  # 1 - 0.01
    assert "-0.6990 hello -2.0000" in text  # 1/5 of the words, back-off log10(0.01)
    assert "public <utterance> = look up | stop;" in jsgf_grammar(["stop", "look up"])
    with pytest.raises(ValueError):
        GarbageWeights(garbage_start=1.0)


@pytest.mark.unit
def test_written_forms_spell_split_names_and_numbers_as_a_transcriber_would() -> None:
    assert written_forms("look up to the left", "look up to the left") == ("look up to the left",)
    assert written_forms("tenhut", "ten hut") == ("ten hut", "ten-hut", "tenhut", "10 hut", "10-hut")
    assert written_forms("bumper leftish", "bumper left ish") == (
        "bumper left ish",
        "bumper left-ish",
        "bumper leftish",
    )
    with pytest.raises(ValueError, match="pronounceable"):
        written_forms("tenhut", "ten hat")


@pytest.mark.unit
def test_a_phrase_said_again_is_written_as_a_transcriber_writes_it() -> None:
    ways = said_again(("stop", "stop moving"))
    assert ways[:2] == ("stop", "stop moving")
    written = {"stop stop", "stop, stop", "stop. Stop. Stop", "stop! Stop", "stop moving, stop moving"}
    assert written <= set(ways)
    assert "stop, stop, stop, stop" not in ways and "stop stop moving" not in ways
    assert said_again(("halt",), times=1) == ("halt",)
