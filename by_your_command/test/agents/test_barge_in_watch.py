"""The barge-in judge and its state (agents/barge_in.py), without the runtime: speech counted from
the VAD's onset, words that are not backchannels, a window that ends the wait, and a transcript
that never catches up. (Through the runtime: test_barge_in.py; through the real VAD and player:
test/agent_process/test_barge_in_graph.py.)"""

from __future__ import annotations

import pytest

from by_your_command.agents.barge_in import (
    WINDOWS_BEFORE_GIVING_UP,
    BargeInWatch,
    Evidence,
    Rules,
    Verdict,
    judge,
)
from by_your_command.agents.reply_audio import ReplyAudio
from by_your_command.agents.turn import Turn

pytestmark = pytest.mark.unit

RULES = Rules(min_ms=400, min_words=2, window_s=1.5)


def speech(ms: float, pre_roll_ms: float = 0.0, ended: bool = False, number: int = 2) -> Turn:
    turn = Turn(number, "voice", 0.0, 1 << 20, utterance_id=number)
    turn.received_ms, turn.unvoiced_ms = ms + pre_roll_ms, pre_roll_ms
    turn.audio += bytes(2 * 16 * int(ms + pre_roll_ms))
    if ended:
        turn.ended_at = 1.0
    return turn


def reply() -> ReplyAudio:
    return ReplyAudio("r1", "item-r1", 24000, "talker-1", 1, 1)


@pytest.mark.parametrize(
    ("evidence", "verdict"),
    [
        (Evidence(300, False, 0, None, False), Verdict.WAIT),  # too short yet
        (Evidence(300, True, 0, None, False), Verdict.FALSE),  # ended short: a cough
        (Evidence(300, False, 1, None, False), Verdict.FALSE),  # the window passed short
        (Evidence(500, False, 0, 2, True), Verdict.CONFIRMED),  # long enough, two words
        (Evidence(500, True, 0, 1, True), Verdict.FALSE),  # "okay, yeah": one word that counts
        (Evidence(500, True, 0, 1, False), Verdict.WAIT),  # its transcript is still coming
        (Evidence(500, True, WINDOWS_BEFORE_GIVING_UP, None, False), Verdict.FALSE),  # never came
    ],
)
def test_the_judge(evidence: Evidence, verdict: Verdict) -> None:
    assert judge(evidence, RULES) is verdict


LONG = Rules(min_ms=400, min_words=2, window_s=1.5, long_ms=900)


@pytest.mark.parametrize(
    ("evidence", "verdict"),
    [
        (Evidence(1024, True, 0, 1, True), Verdict.CONFIRMED),  # "wait a moment" heard "wait um oh"
        (Evidence(900, False, 0, 1, True), Verdict.CONFIRMED),
        (Evidence(600, True, 0, 1, True), Verdict.FALSE),  # "uh-huh" heard "little": short
        (Evidence(1300, True, 0, 0, True), Verdict.FALSE),  # "yeah, okay, uh-huh": only backchannels
        (Evidence(1300, False, 0, None, False), Verdict.WAIT),  # no words yet
    ],
)
def test_long_speech_needs_one_word_that_is_not_a_backchannel(evidence: Evidence, verdict: Verdict) -> None:
    assert judge(evidence, LONG) is verdict
    if evidence.speech_ms >= LONG.long_ms and evidence.words == 1:
        assert judge(evidence, RULES) is not Verdict.CONFIRMED  # without the rule: two words needed


def test_the_pre_roll_is_not_speech_and_the_first_utterance_over_the_reply_is_held() -> None:
    watch = BargeInWatch(RULES)
    cough = speech(96, pre_roll_ms=480, ended=True)  # a cough with the VAD's pre-roll: 576 ms of audio
    assert not watch.join(cough)  # nothing pending: an utterance like any other
    watch.start(reply(), now=10.0)
    assert watch.join(cough) and cough.held and watch.judges(cough)
    assert not watch.join(speech(500, number=3))  # one utterance per barge-in
    verdict, evidence = watch.judge(now=10.2)
    assert (verdict, evidence.speech_ms) == (Verdict.FALSE, 96.0)
    pending, turn = watch.end()
    assert pending is not None and pending.stream_id == "talker-1" and turn is cough
    assert watch.pending is None and watch.deadline() is None


def test_the_windows_deadline_moves_once_judged_and_a_failed_transcriber_leaves_the_length() -> None:
    watch = BargeInWatch(RULES)
    watch.start(reply(), now=10.0)
    talking = speech(600)
    watch.join(talking)
    assert watch.deadline() == 11.5
    assert watch.judge(now=11.0)[0] is Verdict.WAIT  # long enough, no words yet
    assert watch.judge(now=11.5)[0] is Verdict.WAIT  # the window passed: the transcript may come
    assert watch.deadline() == 13.0  # the next window
    assert watch.judge(now=13.0)[0] is Verdict.FALSE  # given up: no words
    watch.start(reply(), now=20.0, turn=talking, resumed=True)
    assert watch.pending is not None and watch.pending.resumed and watch.turn is talking
    watch.pending.transcriber_failed = True
    assert watch.judge(now=20.1)[0] is Verdict.CONFIRMED  # its 600 ms of speech decide
