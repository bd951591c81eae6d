"""EchoGate: which blocks the robot's own voice may be in, judged on a scripted clock."""

from __future__ import annotations

import pytest

from by_your_command.audio.echo_gate import TRUSTED_STAMP_NS, EchoGate

MS = 1_000_000
T0 = 1_800_000_000_000_000_000  # an epoch-like clock: stamps are wall-clock capture times


def block(start_ms: float) -> tuple[int, int, int]:
    """A 64 ms block (1024 samples at 16 kHz) captured from T0 + start_ms on."""
    return T0 + int(start_ms * MS), 1024, 16000


@pytest.mark.unit
def test_blocks_captured_while_the_robot_speaks_are_gated_whenever_they_arrive() -> None:
    gate = EchoGate(tail_ms=300)
    assert gate.admits(*block(0), now_ns=T0 + 70 * MS)
    assert gate.set_speaking(True, T0 + 1000 * MS) is True
    assert not gate.set_speaking(True, T0 + 1100 * MS)  # repeated: no new spell
    # Captured before the robot spoke, arriving after: the user's.
    assert gate.admits(*block(900), now_ns=T0 + 1200 * MS)
    assert not gate.admits(*block(1500), now_ns=T0 + 1570 * MS)
    assert gate.set_speaking(False, T0 + 3000 * MS) is False
    # Captured during the spell but queued past its end: still the robot's.
    assert not gate.admits(*block(2900), now_ns=T0 + 3400 * MS)
    # The tail: the room's echo after the robot stops.
    assert not gate.admits(*block(3200), now_ns=T0 + 3270 * MS)
    assert gate.admits(*block(3300), now_ns=T0 + 3370 * MS)


@pytest.mark.unit
def test_a_block_stamped_across_the_start_of_a_spell_is_gated() -> None:
    gate = EchoGate(tail_ms=0)
    gate.set_speaking(True, T0 + 1000 * MS)
    assert not gate.admits(*block(950), now_ns=T0 + 1020 * MS)


@pytest.mark.unit
@pytest.mark.parametrize("stamp", [0, T0 - 2 * TRUSTED_STAMP_NS, T0 + 3600 * 1000 * MS])
def test_stamps_on_another_clock_are_judged_by_arrival(stamp: int) -> None:
    gate = EchoGate(tail_ms=300)
    gate.set_speaking(True, T0)
    assert not gate.admits(stamp, 1024, 16000, now_ns=T0 + 10 * MS)
    gate.set_speaking(False, T0 + 1000 * MS)
    assert not gate.admits(stamp, 1024, 16000, now_ns=T0 + 1200 * MS)  # in the tail
    assert gate.admits(stamp, 1024, 16000, now_ns=T0 + 1400 * MS)


@pytest.mark.unit
def test_memory_is_bounded() -> None:
    gate = EchoGate(tail_ms=0)
    for spell in range(1000):
        gate.set_speaking(True, T0 + spell * 10 * MS)
        gate.set_speaking(False, T0 + (spell * 10 + 5) * MS)
    assert len(gate._spells) <= 16
    assert gate.admits(*block(10_001), now_ns=T0 + 10_070 * MS)
