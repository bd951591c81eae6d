"""HalfDuplexGate: the robot's voice starts no utterance, but an utterance the user began before
the robot spoke is heard to its end, for at most the hold (judged on a scripted clock)."""

from __future__ import annotations

import pytest

from by_your_command.vad.half_duplex import HalfDuplexGate

MS = 1_000_000
BLOCK = 1024  # 64 ms at 16 kHz
RATE = 16000
START = 1_000_000 * MS  # the scripted clock's origin, far from 0 (an empty stamp)


def admitted(gate: HalfDuplexGate, at_ms: int) -> bool:
    """Whether a block captured at `at_ms` (and arriving at once) is admitted."""
    stamp = START + at_ms * MS
    return gate.admits(stamp, BLOCK, RATE, stamp + 64 * MS)


@pytest.mark.unit
def test_an_utterance_begun_before_the_robot_spoke_is_heard_until_the_hold_ends() -> None:
    gate = HalfDuplexGate(tail_ms=300, hold_ms=2000)
    assert not gate.set_speaking(True, START + 1000 * MS, mid_utterance=True)  # not cut
    assert gate.holding
    assert admitted(gate, 1000) and admitted(gate, 2900)
    assert not admitted(gate, 3000)  # the hold is over: the robot's voice would keep it going
    gate.set_speaking(False, START + 1500 * MS, mid_utterance=True)
    gate.set_speaking(True, START + 2500 * MS, mid_utterance=True)  # another reply, still held
    assert admitted(gate, 2900) and not admitted(gate, 3000)  # the hold is not lengthened
    gate.release()  # the node ends the utterance there
    assert not admitted(gate, 1500)


@pytest.mark.unit
def test_once_the_held_utterance_ends_the_robots_voice_is_not_heard() -> None:
    gate = HalfDuplexGate(tail_ms=300, hold_ms=2000)
    gate.set_speaking(True, START + 1000 * MS, mid_utterance=True)
    gate.release()  # the user stopped talking
    assert not gate.holding and not admitted(gate, 1200)
    assert not gate.set_speaking(False, START + 1500 * MS, mid_utterance=False)
    assert not admitted(gate, 1600)  # the tail
    assert admitted(gate, 1900)


@pytest.mark.unit
def test_speech_begun_while_the_robot_speaks_is_not_held() -> None:
    gate = HalfDuplexGate(tail_ms=300, hold_ms=2000)
    assert gate.set_speaking(True, START + 1000 * MS, mid_utterance=False)  # what the detector holds ends
    assert not gate.holding and not admitted(gate, 1100)


@pytest.mark.unit
def test_a_hold_of_zero_cuts_the_utterance_when_the_robot_speaks() -> None:
    gate = HalfDuplexGate(tail_ms=300, hold_ms=0)
    assert gate.set_speaking(True, START + 1000 * MS, mid_utterance=True)
    assert not gate.holding and not admitted(gate, 1000)
