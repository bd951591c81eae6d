"""Echo control: the gate drops the mic while the assistant speaks (plus a tail), AEC3 removes a
synthetic room echo, external passes everything through."""

from __future__ import annotations

import numpy as np
import pytest
from audio_io.synthetic_room import Room, energy_db, recorded_speech, speech_like

from by_your_command.audio.echo import EchoConfig, EchoController, ReferenceTimeline
from by_your_command.audio.pcm import float_to_int16

RATE = 16000
MS = 1_000_000
BLOCK = 512
BLOCK_NS = BLOCK * 1_000_000_000 // RATE
T0 = 1_700_000_000 * 1_000_000_000


def _block(value: int = 1000) -> np.ndarray:
    return np.full(BLOCK, value, dtype=np.int16)


@pytest.mark.unit
def test_gate_drops_while_speaking_and_for_the_tail() -> None:
    echo = EchoController(EchoConfig(mode="gate", gate_tail_ms=200))
    assert echo.process(_block(), T0, T0) is not None
    echo.set_assistant_speaking(True, T0 + 10 * MS)
    assert echo.process(_block(), T0 + 20 * MS, T0 + 20 * MS) is None
    echo.set_assistant_speaking(False, T0 + 1000 * MS)
    assert echo.process(_block(), T0 + 1100 * MS, T0 + 1100 * MS) is None  # inside the tail
    assert echo.process(_block(), T0 + 1201 * MS, T0 + 1201 * MS) is not None
    assert (echo.stats.blocks_in, echo.stats.blocks_out, echo.stats.blocks_gated) == (4, 2, 2)
    assert echo.stats.samples_gated == 2 * BLOCK


@pytest.mark.unit
def test_gate_with_zero_tail_opens_at_once_and_repeated_false_does_not_extend() -> None:
    echo = EchoController(EchoConfig(mode="gate", gate_tail_ms=0))
    echo.set_assistant_speaking(True, T0)
    echo.set_assistant_speaking(False, T0 + 5 * MS)
    echo.set_assistant_speaking(False, T0 + 50 * MS)  # a repeated False is not a new end of speech
    assert echo.process(_block(), T0 + 5 * MS, T0 + 5 * MS) is not None


@pytest.mark.unit
def test_external_passes_everything_unchanged() -> None:
    echo = EchoController(EchoConfig(mode="external"))
    echo.set_assistant_speaking(True, T0)
    pcm = _block(123)
    out = echo.process(pcm, T0, T0)
    assert out is not None and out.start_ns == T0
    np.testing.assert_array_equal(out.pcm, pcm)


@pytest.mark.unit
@pytest.mark.parametrize(
    "kwargs",
    [{"mode": "loud"}, {"gate_tail_ms": -1}, {"mode": "aec", "sample_rate": 22050}, {"sample_rate": 0}],
)
def test_bad_config_is_a_clear_error(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        EchoConfig(**kwargs)  # type: ignore[arg-type]


@pytest.mark.unit
def test_reference_timeline_reads_by_time_with_silence_in_gaps() -> None:
    timeline = ReferenceTimeline(RATE, history_ms=1000)
    timeline.add(np.arange(1, 161, dtype=np.int16), T0)  # 10 ms
    timeline.add(np.full(160, 7, dtype=np.int16), T0 + 20 * MS)  # after a 10 ms gap
    got = timeline.read(T0 - 5 * MS, 480)  # 5 ms before the first sample
    np.testing.assert_array_equal(got[:80], 0)
    np.testing.assert_array_equal(got[80:240], np.arange(1, 161))
    np.testing.assert_array_equal(got[240:400], 0)
    np.testing.assert_array_equal(got[400:480], 7)


@pytest.mark.unit
def test_reference_timeline_forgets_old_audio() -> None:
    timeline = ReferenceTimeline(RATE, history_ms=100)
    for k in range(20):  # 200 ms of audio in 10 ms blocks
        timeline.add(np.full(160, k + 1, dtype=np.int16), T0 + k * 10 * MS)
    np.testing.assert_array_equal(timeline.read(T0, 160), 0)  # forgotten
    np.testing.assert_array_equal(timeline.read(T0 + 190 * MS, 160), 20)


def run_aec(far: np.ndarray, mic: np.ndarray, rate: int = RATE, reference_lag_blocks: int = 0) -> np.ndarray:
    """Feed played audio and mic audio block by block, as the graph does in real time; the
    reference may arrive `reference_lag_blocks` after the mic block it belongs to."""
    echo = EchoController(EchoConfig(mode="aec", sample_rate=rate))
    outs = []
    samples = len(mic) // BLOCK * BLOCK
    for k in range(0, samples, BLOCK):
        start = T0 + k * 1_000_000_000 // rate
        late = k - reference_lag_blocks * BLOCK
        if late >= 0:
            echo.add_reference(far[late : late + BLOCK], rate, 1, T0 + late * 1_000_000_000 // rate)
        out = echo.process(mic[k : k + BLOCK], start, start)
        if out is not None:
            outs.append(out.pcm)
    return np.concatenate(outs)


def echo_reduction_db(mic: np.ndarray, out: np.ndarray, from_s: float, rate: int = RATE) -> float:
    lo = int(from_s * rate)
    return energy_db(mic[lo : len(out)]) - energy_db(out[lo:])


@pytest.mark.unit
def test_aec_cancels_a_noise_echo_in_a_synthetic_room() -> None:
    rng = np.random.default_rng(3)
    far = float_to_int16(0.2 * rng.standard_normal(6 * RATE))
    mic = Room(delay_ms=120).echo(far, RATE)
    out = run_aec(far, mic)
    reduction = echo_reduction_db(mic, out, from_s=2.0)
    print(f"AEC echo reduction, noise far end: {reduction:.1f} dB")
    assert reduction > 20.0


@pytest.mark.unit
def test_aec_cancels_a_speech_echo_and_keeps_near_end_speech() -> None:
    far = recorded_speech(8, RATE)
    room = Room(delay_ms=150)
    echo_only = room.echo(far, RATE)
    out = run_aec(far, echo_only)
    reduction = echo_reduction_db(echo_only, out, from_s=3.0)
    print(f"AEC echo reduction, speech far end: {reduction:.1f} dB")
    assert reduction > 15.0

    # Double talk: the user speaks while the assistant is silent: the user must get through.
    near = speech_like(8, RATE, seed=9) // 2
    silent_far = np.zeros_like(far)
    out_near = run_aec(silent_far, near)
    assert abs(energy_db(out_near[RATE:]) - energy_db(near[RATE : len(out_near)])) < 3.0


@pytest.mark.unit
def test_aec_waits_for_a_reference_that_arrives_after_the_mic() -> None:
    far = recorded_speech(6, RATE)
    mic = Room(delay_ms=100).echo(far, RATE)
    out = run_aec(far, mic, reference_lag_blocks=1)  # 32 ms late, within the 48 ms wait
    reduction = echo_reduction_db(mic, out, from_s=3.0)
    print(f"AEC echo reduction, reference 32 ms late: {reduction:.1f} dB")
    assert reduction > 15.0


@pytest.mark.unit
def test_a_reference_arriving_after_its_mic_block_releases_it() -> None:
    echo = EchoController(EchoConfig(mode="aec", aec_reference_wait_ms=48))
    assert echo.process(_block(0), T0, 0) is None  # held for its reference
    echo.add_reference(np.zeros(BLOCK, dtype=np.int16), RATE, 1, T0)
    released = echo.drain()
    assert released is not None and released.start_ns == T0 and len(released.pcm) == 480
    assert echo.drain() is None


@pytest.mark.unit
def test_aec_without_any_reference_passes_near_speech_after_the_wait() -> None:
    echo = EchoController(EchoConfig(mode="aec", aec_reference_wait_ms=48))
    outputs = [echo.process(_block(0), T0 + k * BLOCK_NS, 0) for k in range(4)]
    assert outputs[0] is None  # 32 ms held: less than the wait
    assert all(o is not None for o in outputs[1:])


@pytest.mark.unit
def test_aec_output_is_contiguous_and_stamped_by_its_first_sample() -> None:
    echo = EchoController(EchoConfig(mode="aec", aec_reference_wait_ms=0))
    expected_start = T0
    total = 0
    for k in range(10):
        start = T0 + k * BLOCK_NS
        out = echo.process(_block(0), start, start)
        assert out is not None  # 512 samples always complete at least one 10 ms frame
        assert abs(out.start_ns - expected_start) <= 1
        assert len(out.pcm) % 160 == 0
        total += len(out.pcm)
        expected_start = T0 + total * 1_000_000_000 // RATE
    assert total == 10 * BLOCK // 160 * 160


@pytest.mark.unit
def test_aec_accepts_reference_at_another_rate() -> None:
    echo = EchoController(EchoConfig(mode="aec"))
    echo.add_reference(np.ones(480, dtype=np.int16), 24000, 1, T0)
    assert echo.stats.reference_blocks == 1
