"""The one stateful resampler every audio node uses: block-wise output equals the one-shot
resample of the whole signal (no clicks at block edges), no samples are gained or lost over a
long stream (no drift), reset() forgets, and the stamped wrapper keeps time across gaps."""

from __future__ import annotations

import numpy as np
import pytest

from by_your_command.audio.pcm import Int16Array, StampedResampler, StreamResampler, resample

NS = 1_000_000_000
RATE_PAIRS = [(48000, 16000), (44100, 16000), (24000, 16000), (16000, 48000), (8000, 16000), (22050, 16000)]


def tone(seconds: float, rate: int, freq: float = 440.0) -> Int16Array:
    t = np.arange(int(seconds * rate)) / rate
    return np.rint(8000 * np.sin(2 * np.pi * freq * t)).astype(np.int16)


def odd_blocks(total: int, seed: int, high: int = 700) -> list[tuple[int, int]]:
    """(start, size) of ragged blocks covering `total` samples, sizes 1..high (odd ones too)."""
    rng = np.random.default_rng(seed)
    blocks, pos = [], 0
    while pos < total:
        size = int(rng.integers(1, high))
        blocks.append((pos, min(size, total - pos)))
        pos += size
    return blocks


def stream(signal: Int16Array, src: int, dst: int, seed: int = 0) -> Int16Array:
    resampler = StreamResampler(src, dst)
    parts = [resampler.push(signal[start : start + size]) for start, size in odd_blocks(len(signal), seed)]
    parts.append(resampler.flush())
    return np.concatenate(parts)


def click_energy_db(got: Int16Array, reference: Int16Array) -> float:
    """Energy of the difference relative to the signal (dB): clicks at block edges raise it."""
    error = got.astype(np.float64) - reference.astype(np.float64)
    return 10 * float(np.log10((np.sum(error**2) + 1e-9) / np.sum(reference.astype(np.float64) ** 2)))


@pytest.mark.unit
@pytest.mark.parametrize(("src", "dst"), RATE_PAIRS)
def test_blockwise_resampling_matches_whole_signal_resampling(src: int, dst: int) -> None:
    signal = tone(1.0, src)
    whole = resample(signal, src, dst)
    streamed = stream(signal, src, dst)
    assert len(streamed) == len(whole)
    assert np.max(np.abs(streamed.astype(np.int32) - whole.astype(np.int32))) <= 1
    assert click_energy_db(streamed, whole) < -80.0
    # The defect it replaces: resampling each block on its own clicks at every edge.
    per_block = np.concatenate(
        [resample(signal[start : start + size], src, dst) for start, size in odd_blocks(len(signal), 0)]
    )
    n = min(len(per_block), len(whole))
    assert click_energy_db(per_block[:n], whole[:n]) > -40.0


@pytest.mark.unit
@pytest.mark.parametrize(("src", "dst"), RATE_PAIRS)
def test_no_samples_are_gained_or_lost_over_many_blocks(src: int, dst: int) -> None:
    resampler = StreamResampler(src, dst)
    rng = np.random.default_rng(1)
    received = emitted = 0
    for _ in range(3000):
        size = int(rng.integers(1, 400))
        emitted += len(resampler.push(np.zeros(size, dtype=np.int16)))
        received += size
        # While streaming only the filter's reach is held back: 10 / min(rate) s plus one output.
        assert resampler.held_back_s <= 10 / min(src, dst) + 1 / dst + 1e-9
    emitted += len(resampler.flush())
    assert abs(emitted - round(received * dst / src)) <= 1


@pytest.mark.unit
def test_reset_forgets_the_previous_stream() -> None:
    resampler = StreamResampler(48000, 16000)
    resampler.push(tone(0.2, 48000, 1000.0))  # context that must not leak into what follows
    resampler.reset()
    fresh = tone(0.3, 48000, 300.0)
    out = np.concatenate([resampler.push(fresh[:4801]), resampler.push(fresh[4801:]), resampler.flush()])
    whole = resample(fresh, 48000, 16000)
    assert len(out) == len(whole)
    assert np.max(np.abs(out.astype(np.int32) - whole.astype(np.int32))) <= 1
    assert (resampler.received, resampler.emitted) == (0, 0)


@pytest.mark.unit
def test_identity_passes_samples_through_unchanged() -> None:
    resampler = StreamResampler(16000, 16000)
    block = tone(0.01, 16000)
    assert resampler.identity
    np.testing.assert_array_equal(resampler.push(block), block)
    assert len(resampler.flush()) == 0


@pytest.mark.unit
@pytest.mark.parametrize(
    ("src", "dst"), [(0, 16000), (16000, -1), (4294967291, 16000), (1000003, 16000), (16001, 16000)]
)
def test_absurd_rates_are_a_clear_error(src: int, dst: int) -> None:
    with pytest.raises(ValueError):
        StreamResampler(src, dst)


@pytest.mark.unit
def test_stamped_resampler_stamps_output_by_its_first_sample() -> None:
    resampler = StampedResampler(16000, tolerance_ns=2_000_000)
    signal = tone(0.5, 48000)
    t0 = 5 * NS
    pieces = []
    for start, size in odd_blocks(len(signal), seed=2, high=1500):
        pieces += resampler.push(signal[start : start + size], 48000, t0 + start * NS // 48000)
    pieces += resampler.flush()
    assert pieces[0].restart and not any(p.restart for p in pieces[1:])
    total = 0
    for piece in pieces:  # contiguous: each starts where the previous ended, on the 16 kHz grid
        assert abs(piece.start_ns - (t0 + total * NS // 16000)) <= 1
        total += len(piece.pcm)
    whole = resample(signal, 48000, 16000)
    np.testing.assert_allclose(np.concatenate([p.pcm for p in pieces]), whole, atol=1)
    assert resampler.restarts == 0


@pytest.mark.unit
def test_stamped_resampler_restarts_on_a_gap_a_jump_back_or_a_new_rate_but_not_on_jitter() -> None:
    resampler = StampedResampler(16000, tolerance_ns=5_000_000)
    block = tone(0.032, 48000)  # 1536 samples = 32 ms
    t = 10 * NS
    step = 32_000_000
    resampler.push(block, 48000, t)
    resampler.push(block, 48000, t + step + 3_000_000)  # 3 ms jitter: the same stream
    assert resampler.restarts == 0
    gap = resampler.push(block, 48000, t + 3 * step)  # one block lost
    assert resampler.restarts == 1
    assert not gap[0].restart and gap[-1].restart  # the old stream's tail, then the new stream
    assert gap[-1].start_ns == t + 3 * step  # the new stream keeps its own stamp
    resampler.push(block, 48000, t)  # a jump back
    assert resampler.restarts == 2
    new_rate = resampler.push(tone(0.032, 24000), 24000, t + step)
    assert resampler.restarts == 3 and new_rate[-1].restart
