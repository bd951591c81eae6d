"""Double talk in aec mode: the user talking over the robot at their usual level comes through the
echo control nearly undistorted and starts an utterance at once, while the robot's voice alone
stays attenuated and starts none; the linear canceller converges, and the user's voice does not
pull its output filter off the echo."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from audio_io.synthetic_room import Conversation, Room, conversation, energy_db, recorded_speech
from audio_io.test_echo import ROBOT_ROOM, utterance_starts

from by_your_command.audio.echo import EchoConfig, EchoController
from by_your_command.audio.echo_linear import (
    COUPLING_INITIAL_DB,
    COUPLING_WARMUP_BLOCKS,
    LinearEchoCanceller,
    ResidualEchoSuppressor,
    to_float,
)
from by_your_command.audio.pcm import float_to_int16
from by_your_command.vad.model import SileroModel

RATE = 16000
BLOCK = 512
T0 = 1_700_000_000 * 1_000_000_000
LINEAR = EchoConfig(mode="aec")  # the default engine: linear + per-band residual suppression
OLD = EchoConfig(mode="aec", aec_engine="webrtc")  # AEC3 + whole-frame guard (the old default)
LONG_TAIL_ROOM = Room(delay_ms=150, reverb_ms=250, reverb_gain=0.4)  # ~0.9 s of response


def output_of(talk: Conversation, config: EchoConfig) -> np.ndarray:
    """The echo control's output for `talk`, laid on the mic's sample clock by its stamps."""
    echo = EchoController(config)
    echo.set_assistant_speaking(True, T0)
    out = np.zeros(len(talk.mic))
    for k in range(0, len(talk.mic) // BLOCK * BLOCK, BLOCK):
        start = T0 + k * 1_000_000_000 // RATE
        echo.add_reference(talk.played[k : k + BLOCK], RATE, 1, start)
        for block in echo.process(talk.mic[k : k + BLOCK], start, start) + echo.drain():
            at = round((block.start_ns - T0) * RATE / 1e9)
            n = max(0, min(len(block.pcm), len(out) - at))
            out[at : at + n] = block.pcm[:n]
    return out


def near_end_correlations(talk: Conversation, config: EchoConfig) -> list[float]:
    """Per user sentence: Pearson correlation of the output with what the same echo control
    outputs for the user alone, nothing played (the bench's measure)."""
    assert talk.near is not None
    heard = output_of(talk, config)
    alone = output_of(dataclasses.replace(talk, mic=talk.near, played=np.zeros_like(talk.played)), config)
    values = []
    for begin, end in talk.user_spans:
        span = slice(int(begin * RATE), int(end * RATE))
        a, b = heard[span] - heard[span].mean(), alone[span] - alone[span].mean()
        values.append(float(np.dot(a, b) / np.sqrt(np.dot(a, a) * np.dot(b, b))))
    return values


@pytest.fixture(scope="module")
def silero() -> SileroModel:
    return SileroModel()


@pytest.fixture(scope="module")
def equal_level_talk() -> Conversation:
    """The robot's echo as loud at the mic as the user (-26 dBFS, a user a metre away)."""
    return conversation(RATE, ROBOT_ROOM, echo_dbfs=-26.0, user_dbfs=-26.0, user_at_s=(3.0, 6.5, 10.0))


@pytest.mark.unit
def test_a_user_at_equal_level_over_the_robot_comes_through_undistorted(
    equal_level_talk: Conversation,
) -> None:
    correlations = near_end_correlations(equal_level_talk, LINEAR)
    assert min(correlations) >= 0.9, correlations


@pytest.mark.unit
def test_a_louder_robot_still_leaves_the_user_recognisable() -> None:
    talk = conversation(RATE, ROBOT_ROOM, echo_dbfs=-20.0, user_dbfs=-26.0, user_at_s=(3.0, 6.5, 10.0))
    correlations = near_end_correlations(talk, LINEAR)
    assert min(correlations) >= 0.8, correlations


@pytest.mark.unit
def test_a_user_at_equal_level_starts_an_utterance_within_a_few_frames(
    equal_level_talk: Conversation, silero: SileroModel
) -> None:
    """Silero's onset on the output falls within 8 of its 32 ms frames of the user's first sound
    (the old guard needed 7-25 frames or missed the sentence)."""
    starts = utterance_starts(equal_level_talk, LINEAR, silero)
    for begin, _ in equal_level_talk.user_spans:
        assert any(begin - 0.1 <= s <= begin + 8 * BLOCK / RATE for s in starts), (begin, starts)


@pytest.mark.unit
def test_the_robot_alone_stays_attenuated_at_least_30_db_and_starts_nothing(silero: SileroModel) -> None:
    for room in (ROBOT_ROOM, Room(delay_ms=120)):
        talk = conversation(RATE, room, echo_dbfs=-20.0)
        out = output_of(talk, LINEAR)
        lo, hi = 3 * RATE, len(talk.mic) - RATE // 2  # converged, while the robot speaks
        attenuation = energy_db(talk.mic[lo:hi]) - energy_db(float_to_int16(out[lo:hi] / 32768.0))
        assert attenuation >= 30.0, (room, attenuation)
        assert utterance_starts(talk, LINEAR, silero) == []


@pytest.mark.unit
def test_the_robot_alone_in_a_long_tail_room_stays_35_db_down_and_starts_nothing(silero: SileroModel) -> None:
    """The filter spans the room's response and converges on speech within seconds; the
    suppressor keeps the syllables it has not learned yet from opening the frame (NLMS over
    640 ms with single-block openings left 31 dB here)."""
    talk = conversation(RATE, LONG_TAIL_ROOM, echo_dbfs=-20.0)
    out = output_of(talk, LINEAR)
    lo, hi = 3 * RATE, len(talk.mic) - RATE // 2
    attenuation = energy_db(talk.mic[lo:hi]) - energy_db(float_to_int16(out[lo:hi] / 32768.0))
    assert attenuation >= 35.0, attenuation
    assert utterance_starts(talk, LINEAR, silero) == []


@pytest.mark.unit
def test_the_canceller_knows_how_much_echo_it_may_still_miss() -> None:
    """Its coefficients' variance times the reference: large while the filter is new, at least
    6 dB smaller once it has converged on the robot's voice."""
    talk = conversation(RATE, Room(delay_ms=120), echo_dbfs=-20.0)
    far, mic = to_float(talk.played), to_float(talk.mic)
    canceller = LinearEchoCanceller(block=160, partitions=80, step=1.0, margin_db=6.0)
    missed = []
    for k in range(0, len(mic) // 160 * 160, 160):
        canceller.process(mic[k : k + 160], far[k : k + 160])
        missed.append(float(np.sum(canceller.uncertain_echo)))
    early, late = np.mean(missed[100:300]), np.mean(missed[900:1200])  # 1-3 s vs 9-12 s
    assert 10 * np.log10(early / late) >= 6.0, (early, late)


def _suppress(suppressor: ResidualEchoSuppressor, error: np.ndarray, level: float) -> np.ndarray:
    """`error` through `suppressor` block by block, the echo estimate and the reference both a
    flat spectrum of power `level` per bin (the robot sounding all along)."""
    n = suppressor.block
    flat = np.full(n + 1, np.sqrt(level), dtype=np.complex128)
    return np.concatenate(
        [suppressor.process(error[k : k + n], flat, flat, True) for k in range(0, len(error), n)]
    )


def _suppressor() -> ResidualEchoSuppressor:
    return ResidualEchoSuppressor(
        160, overestimate=4.0, floor=0.1, tail_decay_db=0.5, margin_db=6.0, mute=1e-3
    )


@pytest.mark.unit
def test_one_block_that_looks_like_the_user_does_not_open_the_frame() -> None:
    """A click (one 10 ms frame clearly above the residual: a syllable the filter has not
    learned) stays muted; the user, who goes on, opens it after two blocks."""
    rng = np.random.default_rng(8)
    suppressor = _suppressor()
    _suppress(suppressor, 1e-4 * rng.standard_normal(300 * 160), level=1e-2)  # echo, cancelled
    click = np.zeros(4 * 160)
    click[159] = 0.05  # at the end of a block: it falls in the middle of one window only
    assert np.max(np.abs(_suppress(suppressor, click, level=1e-2))) < 0.005
    voice = 0.1 * rng.standard_normal(20 * 160)
    out = _suppress(suppressor, voice, level=1e-2)
    assert np.std(out[-10 * 160 :]) >= 0.5 * np.std(voice)


@pytest.mark.unit
def test_the_coupling_is_learned_down_slowly_while_the_filter_is_new() -> None:
    """For the first COUPLING_WARMUP_BLOCKS the echo left against the reference is learned down
    at 5 dB/s (a new filter's error swings widely), then at the usual 20 dB/s."""
    rng = np.random.default_rng(9)
    suppressor = _suppressor()
    _suppress(suppressor, 1e-4 * rng.standard_normal(100 * 160), level=1e-2)
    assert np.min(suppressor.coupling_db) >= COUPLING_INITIAL_DB - 100 * 0.05 - 1e-6
    _suppress(suppressor, 1e-4 * rng.standard_normal((COUPLING_WARMUP_BLOCKS + 100) * 160), level=1e-2)
    assert np.max(suppressor.coupling_db) < -20.0


@pytest.mark.unit
def test_the_gain_follows_the_echo_estimate_while_the_frame_decision_holds_it() -> None:
    """After a loud stretch of echo the estimate drops (the robot's next syllable is quiet): the
    user over it passes whole at once (held, the estimate kept taking them down ~2 dB), while
    echo left below the held estimate (the room's tail) keeps the frame muted."""
    rng = np.random.default_rng(10)
    quiet = np.full(161, np.sqrt(1e-6), dtype=np.complex128)
    loud = np.full(161, np.sqrt(1e-2), dtype=np.complex128)

    def run(error: np.ndarray, echo: np.ndarray, suppressor: ResidualEchoSuppressor) -> np.ndarray:
        return np.concatenate(
            [suppressor.process(error[k : k + 160], echo, quiet, True) for k in range(0, len(error), 160)]
        )

    after_loud_echo = []
    for _ in range(2):
        suppressor = _suppressor()
        run(0.0056 * rng.standard_normal(50 * 160), loud, suppressor)  # echo left as loud as the estimate
        after_loud_echo.append(suppressor)
    user = 0.016 * rng.standard_normal(12 * 160)  # 9 dB above the loud echo left
    out = run(user, quiet, after_loud_echo[0])
    assert np.std(out[3 * 160 :]) >= 0.95 * np.std(user[2 * 160 : -160])
    tail = 0.001 * rng.standard_normal(14 * 160)  # 15 dB below it
    out = run(tail, quiet, after_loud_echo[1])
    # once the 100 ms hangover some blocks of the loud stretch left is over
    assert np.std(out[-3 * 160 :]) < 0.01 * np.std(tail)


@pytest.mark.unit
def test_a_new_filter_does_not_take_the_robots_unlearned_syllables_for_double_talk() -> None:
    """While it learns, the filter's output jumps with every syllable it has not heard yet; its
    variances account for that, so the robot alone is never double talk (before, 2.6 s of this
    reply were, learning at a quarter step), while a user over the converged filter still is."""
    far_alone = conversation(RATE, ROBOT_ROOM, echo_dbfs=-20.0)
    with_user = conversation(RATE, ROBOT_ROOM, echo_dbfs=-20.0, user_dbfs=-26.0, user_at_s=(8.0,))
    counts = []
    for talk in (far_alone, with_user):
        canceller = LinearEchoCanceller(block=160, partitions=80, step=1.0, margin_db=6.0)
        cancel(canceller, to_float(talk.mic), to_float(talk.played))
        counts.append(canceller.stats.double_talk_blocks)
    assert counts[0] == 0
    assert counts[1] > 0


def cancel(
    canceller: LinearEchoCanceller, mic: np.ndarray, far: np.ndarray
) -> np.ndarray:  # whole signals, block by block
    n = canceller.block
    return np.concatenate(
        [canceller.process(mic[k : k + n], far[k : k + n]) for k in range(0, len(mic) // n * n, n)]
    )


@pytest.mark.unit
def test_the_linear_canceller_converges_and_double_talk_does_not_pull_it_off() -> None:
    rng = np.random.default_rng(5)
    seconds = 10
    far = 0.1 * rng.standard_normal(seconds * RATE)
    room = Room(delay_ms=60, reverb_ms=80, reverb_gain=0.1, noise_dbfs=-90.0)
    echo = to_float(room.echo(float_to_int16(far), RATE))
    near = np.zeros_like(far)
    near[4 * RATE : 6 * RATE] = 0.1 * rng.standard_normal(2 * RATE)  # the user, as loud as the echo
    canceller = LinearEchoCanceller(block=160, partitions=30, step=0.5, margin_db=6.0)
    error = cancel(canceller, echo + near, far)

    def attenuation(lo: float, hi: float) -> float:
        part = slice(int(lo * RATE), int(hi * RATE))
        return float(10 * np.log10(np.mean(echo[part] ** 2) / np.mean((error[part] - near[part]) ** 2)))

    before, during, after = attenuation(3.0, 4.0), attenuation(4.5, 6.0), attenuation(6.0, 7.0)
    assert before >= 25.0
    assert during >= before - 6.0  # the echo is still cancelled under the user's voice
    assert after >= before - 6.0
    assert canceller.stats.double_talk_blocks > 0


@pytest.mark.unit
def test_the_residual_suppressor_passes_everything_when_nothing_played() -> None:
    rng = np.random.default_rng(6)
    signal = 0.1 * rng.standard_normal(20 * 160)
    suppressor = ResidualEchoSuppressor(
        160, overestimate=4.0, floor=0.1, tail_decay_db=0.5, margin_db=6.0, mute=0.01
    )
    silence = np.zeros(161, dtype=np.complex128)
    out = np.concatenate(
        [suppressor.process(signal[k : k + 160], silence, silence, False) for k in range(0, len(signal), 160)]
    )
    np.testing.assert_allclose(out[160:], signal[:-160], atol=1e-9)  # one block late, unchanged


@pytest.mark.unit
@pytest.mark.parametrize(
    "kwargs",
    [
        {"aec_engine": "speex"},
        {"aec_filter_ms": 0},
        {"aec_step": 0.0},
        {"aec_step": 1.5},
        {"aec_step": float("nan")},
        {"aec_double_talk_margin_db": 0.0},
        {"aec_double_talk_margin_db": float("nan")},
        {"echo_guard_floor_db": 0.0},
        {"echo_guard_floor_db": -90.0},
        {"echo_guard_margin_db": float("nan")},
    ],
)
def test_bad_double_talk_config_is_a_clear_error(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        EchoConfig(mode="aec", **kwargs)  # type: ignore[arg-type]


@pytest.mark.unit
def test_the_old_guard_distorted_the_same_double_talk(equal_level_talk: Conversation) -> None:
    """The reference point the tests above improve on: AEC3 with the whole-frame guard."""
    assert min(near_end_correlations(equal_level_talk, OLD)) < 0.8


@pytest.mark.unit
def test_the_canceller_follows_an_echo_path_change_but_not_a_voice() -> None:
    """The echo path moves by 5 ms mid-reply (a turned head, a stamp off within tolerance): the
    output filter, which then adds echo, relearns within seconds instead of freezing as if the
    user talked; a user as loud as the echo over the same reply is no path change."""
    rng = np.random.default_rng(6)
    seconds = 12
    far = 0.1 * rng.standard_normal(seconds * RATE)
    before = to_float(Room(delay_ms=20, reverb_ms=60, noise_dbfs=-90.0).echo(float_to_int16(far), RATE))
    after = to_float(Room(delay_ms=25, reverb_ms=60, noise_dbfs=-90.0).echo(float_to_int16(far), RATE))
    echo = np.concatenate([before[: 5 * RATE], after[5 * RATE :]])
    canceller = LinearEchoCanceller(block=160, partitions=30, step=1.0, margin_db=6.0)
    error = cancel(canceller, echo, far)
    part = slice(9 * RATE, 12 * RATE)
    assert energy_db(float_to_int16(echo[part])) - energy_db(float_to_int16(error[part])) >= 25.0
    assert canceller.stats.path_changes >= 1

    near = np.zeros_like(far)
    near[6 * RATE : 9 * RATE] = 0.1 * rng.standard_normal(3 * RATE)
    talked_over = LinearEchoCanceller(block=160, partitions=30, step=1.0, margin_db=6.0)
    cancel(talked_over, before + near, far)
    assert talked_over.stats.path_changes == 0
    assert talked_over.stats.double_talk_blocks > 0


@pytest.mark.unit
def test_a_mic_stamp_jump_within_the_tolerance_leaves_the_next_reply_cancelled() -> None:
    """Two replies; between them the mic loses 10 ms, less than stamp_tolerance_ms, so its
    timeline goes on unbroken and the mic is 10 ms late against the reference: the next reply
    still comes out cancelled (it came out at full echo level, frozen as double talk)."""
    far = recorded_speech(8, RATE)
    room = Room(delay_ms=30, reverb_ms=60, noise_dbfs=-90.0)
    mic = room.echo(far, RATE)
    echo = EchoController(LINEAR)
    clock = T0
    replies: list[np.ndarray] = []
    for _ in range(2):
        echo.set_assistant_speaking(True, clock)
        out: list[np.ndarray] = []
        for k in range(0, len(far) // BLOCK * BLOCK, BLOCK):
            start = clock + k * 1_000_000_000 // RATE
            echo.add_reference(far[k : k + BLOCK], RATE, 1, start)
            out += [block.pcm for block in echo.process(mic[k : k + BLOCK], start, start) + echo.drain()]
        clock += len(far) // BLOCK * BLOCK * 1_000_000_000 // RATE
        echo.set_assistant_speaking(False, clock)
        silence = np.zeros(RATE, dtype=np.int16)
        for k in range(0, RATE, BLOCK):
            start = clock + k * 1_000_000_000 // RATE
            out += [block.pcm for block in echo.process(silence[k : k + BLOCK], start, start)]
        clock += RATE * 1_000_000_000 // RATE + 10_000_000  # 10 ms of mic never arrive
        replies.append(np.concatenate(out))
    assert echo.stats.mic_resyncs == 0 and echo.stats.path_changes >= 1  # relearned, not resynced
    second = replies[1][3 * RATE : 7 * RATE]
    assert energy_db(mic[3 * RATE : 7 * RATE]) - energy_db(second) >= 25.0
