"""Echo control: the gate drops the mic while the assistant speaks (plus a tail), AEC3 removes a
synthetic room echo (and its timeline, stamps, resampling and no-wait-when-quiet rules hold), the
echo guard keeps residual echo from the real Silero VAD, external passes everything through."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from audio_io.synthetic_room import Conversation, Room, conversation, energy_db, recorded_speech, speech_like

from by_your_command.audio.echo import Block, EchoConfig, EchoController, ReferenceTimeline
from by_your_command.audio.pcm import float_to_int16, resample
from by_your_command.vad.config import VadConfig
from by_your_command.vad.detector import VoiceDetector
from by_your_command.vad.model import SileroModel
from by_your_command.vad.segmenter import VoiceActivity

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
    assert echo.process(_block(), T0, T0)
    echo.set_assistant_speaking(True, T0 + 10 * MS)
    assert echo.process(_block(), T0 + 20 * MS, T0 + 20 * MS) == []
    echo.set_assistant_speaking(False, T0 + 1000 * MS)
    assert echo.process(_block(), T0 + 1100 * MS, T0 + 1100 * MS) == []  # inside the tail
    assert echo.process(_block(), T0 + 1201 * MS, T0 + 1201 * MS)
    assert (echo.stats.blocks_in, echo.stats.blocks_out, echo.stats.blocks_gated) == (4, 2, 2)
    assert echo.stats.samples_gated == 2 * BLOCK


@pytest.mark.unit
def test_gate_with_zero_tail_opens_at_once_and_repeated_false_does_not_extend() -> None:
    echo = EchoController(EchoConfig(mode="gate", gate_tail_ms=0))
    echo.set_assistant_speaking(True, T0)
    echo.set_assistant_speaking(False, T0 + 5 * MS)
    echo.set_assistant_speaking(False, T0 + 50 * MS)  # a repeated False is not a new end of speech
    assert echo.process(_block(), T0 + 5 * MS, T0 + 5 * MS)


@pytest.mark.unit
def test_external_passes_everything_unchanged() -> None:
    echo = EchoController(EchoConfig(mode="external"))
    echo.set_assistant_speaking(True, T0)
    pcm = _block(123)
    [out] = echo.process(pcm, T0, T0)
    assert out.start_ns == T0
    np.testing.assert_array_equal(out.pcm, pcm)


@pytest.mark.unit
@pytest.mark.parametrize(
    "kwargs",
    [
        {"mode": "loud"},
        {"gate_tail_ms": -1},
        {"mode": "aec", "sample_rate": 22050},
        {"sample_rate": 0},
        {"stamp_tolerance_ms": 0},
        {"echo_guard_margin_db": -1.0},
        {"echo_guard_release_db_per_s": 0.0},
    ],
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


def run_aec(
    far: np.ndarray,
    mic: np.ndarray,
    rate: int = RATE,
    reference_lag_blocks: int = 0,
    config: EchoConfig | None = None,
) -> np.ndarray:
    """Feed played audio and mic audio block by block, as the graph does in real time, with the
    robot speaking throughout; the reference may arrive `reference_lag_blocks` after the mic block
    it belongs to. Returns the output laid on the mic's timeline (by the output stamps)."""
    echo = EchoController(config or EchoConfig(mode="aec", sample_rate=rate, echo_guard=False))
    echo.set_assistant_speaking(True, T0)
    out = np.zeros(len(mic), dtype=np.int16)
    samples = len(mic) // BLOCK * BLOCK
    for k in range(0, samples, BLOCK):
        start = T0 + k * 1_000_000_000 // rate
        late = k - reference_lag_blocks * BLOCK
        if late >= 0:
            echo.add_reference(far[late : late + BLOCK], rate, 1, T0 + late * 1_000_000_000 // rate)
        for block in echo.process(mic[k : k + BLOCK], start, start) + echo.drain():
            first = round((block.start_ns - T0) * rate / 1_000_000_000)
            out[first : first + len(block.pcm)] = block.pcm[: len(mic) - first]
    return out[:samples]


def echo_reduction_db(mic: np.ndarray, out: np.ndarray, from_s: float, rate: int = RATE) -> float:
    lo = int(from_s * rate)
    return energy_db(mic[lo : len(out)]) - energy_db(out[lo:])


# Each engine as it is meant to run: AEC3 measured alone (its guard mutes whole frames, which
# says nothing about cancelling), the linear filter with its residual suppressor (its default).
ENGINES = {
    "webrtc": EchoConfig(mode="aec", aec_engine="webrtc", echo_guard=False),
    "linear": EchoConfig(mode="aec", aec_engine="linear"),
}
NOISE_REDUCTION_DB = {"webrtc": 20.0, "linear": 30.0}
SPEECH_REDUCTION_DB = {"webrtc": 15.0, "linear": 30.0}


@pytest.mark.unit
@pytest.mark.parametrize("engine", ENGINES)
def test_aec_cancels_a_noise_echo_in_a_synthetic_room(engine: str) -> None:
    rng = np.random.default_rng(3)
    far = float_to_int16(0.2 * rng.standard_normal(6 * RATE))
    mic = Room(delay_ms=120).echo(far, RATE)
    out = run_aec(far, mic, config=ENGINES[engine])
    reduction = echo_reduction_db(mic, out, from_s=2.0)
    print(f"AEC ({engine}) echo reduction, noise far end: {reduction:.1f} dB")
    assert reduction > NOISE_REDUCTION_DB[engine]


@pytest.mark.unit
@pytest.mark.parametrize("engine", ENGINES)
def test_aec_cancels_a_speech_echo_and_keeps_near_end_speech(engine: str) -> None:
    far = recorded_speech(8, RATE)
    room = Room(delay_ms=150)
    echo_only = room.echo(far, RATE)
    out = run_aec(far, echo_only, config=ENGINES[engine])
    reduction = echo_reduction_db(echo_only, out, from_s=3.0)
    print(f"AEC ({engine}) echo reduction, speech far end: {reduction:.1f} dB")
    assert reduction > SPEECH_REDUCTION_DB[engine]

    # The user speaks while the assistant is silent: the user must get through.
    near = speech_like(8, RATE, seed=9) // 2
    silent_far = np.zeros_like(far)
    out_near = run_aec(silent_far, near, config=ENGINES[engine])
    assert abs(energy_db(out_near[RATE:]) - energy_db(near[RATE : len(out_near)])) < 3.0


@pytest.mark.unit
@pytest.mark.parametrize("engine", ENGINES)
def test_aec_waits_for_a_reference_that_arrives_after_the_mic(engine: str) -> None:
    far = recorded_speech(6, RATE)
    mic = Room(delay_ms=100).echo(far, RATE)
    out = run_aec(far, mic, reference_lag_blocks=1, config=ENGINES[engine])  # 32 ms late, within the wait
    reduction = echo_reduction_db(mic, out, from_s=3.0)
    print(f"AEC ({engine}) echo reduction, reference 32 ms late: {reduction:.1f} dB")
    assert reduction > SPEECH_REDUCTION_DB[engine]


@pytest.mark.unit
def test_a_reference_arriving_after_its_mic_block_releases_it() -> None:
    echo = EchoController(EchoConfig(mode="aec", aec_reference_wait_ms=48))
    echo.set_assistant_speaking(True, T0)
    assert echo.process(_block(0), T0, 0) == []  # the robot speaks: held for its reference
    echo.add_reference(np.zeros(BLOCK, dtype=np.int16), RATE, 1, T0)
    [released] = echo.drain()
    delay = echo.aec_delay_samples
    assert released.start_ns == T0 and len(released.pcm) == 480 - delay  # AEC3 holds `delay` back
    assert echo.drain() == []


@pytest.mark.unit
@pytest.mark.parametrize("engine", ENGINES)
def test_while_the_robot_speaks_a_missing_reference_holds_the_mic_at_most_the_wait(engine: str) -> None:
    echo = EchoController(dataclasses.replace(ENGINES[engine], aec_reference_wait_ms=48))
    echo.set_assistant_speaking(True, T0)
    outputs = [echo.process(_block(0), T0 + k * BLOCK_NS, 0) for k in range(4)]
    assert outputs[0] == []  # 32 ms held: less than the wait
    # Then out after the wait, framing and the engine's own delay (the first 10 ms frame is
    # all start-up delay for the linear engine's suppressor, so its first block comes one later).
    first = 1 + (echo.aec_delay_samples >= echo.frame_samples)
    assert all(outputs[first:])
    assert echo.stats.aec_frames_unreferenced > 0


@pytest.mark.unit
def test_nothing_playing_means_no_wait_yet_aec3_is_fed() -> None:
    """The usual state: nobody plays anything. Mic audio goes out with the next block, held back
    only by AEC3's 10 ms framing and its own delay, not the 48 ms reference wait."""
    echo = EchoController(EchoConfig(mode="aec", aec_reference_wait_ms=48))
    delay = echo.aec_delay_samples
    fed = out = 0
    for k in range(20):
        blocks = echo.process(_block(100), T0 + k * BLOCK_NS, T0 + k * BLOCK_NS)
        fed += BLOCK
        out += sum(len(b.pcm) for b in blocks)
        assert blocks, f"block {k} held back"
        assert fed - out < echo.frame_samples + delay  # only framing and AEC3's own delay
    assert echo.stats.aec_frames == fed // 160  # AEC3 kept warm all along
    # The robot starts speaking: from now on mic audio waits (bounded) for its reference again.
    echo.set_assistant_speaking(True, T0 + 20 * BLOCK_NS)
    assert echo.process(_block(100), T0 + 20 * BLOCK_NS, 0) == []
    echo.add_reference(np.zeros(BLOCK, dtype=np.int16), RATE, 1, T0 + 20 * BLOCK_NS)
    assert echo.drain()


@pytest.mark.unit
def test_recently_played_audio_keeps_aligned_mode_for_the_wait() -> None:
    echo = EchoController(EchoConfig(mode="aec", aec_reference_wait_ms=48))
    echo.add_reference(np.full(BLOCK, 500, dtype=np.int16), RATE, 1, T0)  # played, then stopped
    echo.set_assistant_speaking(False, T0 + BLOCK_NS)
    # A mic block right after the reference ended: its reference might still be in flight.
    assert echo.process(_block(0), T0 + BLOCK_NS, 0) == []


def burst_onsets_s(blocks: list[Block], threshold: int = 2000) -> float:
    """Time (s after T0) of the first output sample above `threshold`, read from the stamps."""
    for block in blocks:
        loud = np.nonzero(np.abs(block.pcm.astype(np.int32)) > threshold)[0]
        if len(loud):
            return float((block.start_ns - T0) / 1e9 + loud[0] / RATE)
    raise AssertionError("no burst in the output")


def tone_burst(at_s: float, seconds: float) -> np.ndarray:
    mic = np.zeros(int(seconds * RATE), dtype=np.int16)
    at = int(at_s * RATE)
    mic[at : at + 800] = np.rint(12000 * np.sin(2 * np.pi * 1000 * np.arange(800) / RATE))
    return mic


@pytest.mark.unit
def test_output_is_stamped_with_the_capture_time_of_its_first_sample() -> None:
    """AEC3 delays its output by ~8 ms; the stamps take that off, so a burst captured at 0.5 s
    is found at 0.5 s on the output's stamps."""
    echo = EchoController(EchoConfig(mode="aec"))
    assert echo.aec_delay_samples > 0
    mic = tone_burst(0.5, 1.0)
    blocks = []
    for k in range(0, len(mic) // BLOCK * BLOCK, BLOCK):
        blocks += echo.process(mic[k : k + BLOCK], T0 + k * BLOCK_NS // BLOCK, 0)
    assert abs(burst_onsets_s(blocks) - 0.5) <= 0.001
    for before, after in zip(blocks, blocks[1:], strict=False):  # contiguous, no overlap
        assert abs(after.start_ns - (before.start_ns + len(before.pcm) * 1_000_000_000 // RATE)) <= 1


@pytest.mark.unit
def test_a_lost_mic_block_does_not_shift_the_timeline() -> None:
    echo = EchoController(EchoConfig(mode="aec"))
    mic = tone_burst(0.6, 1.0)
    lost = 5  # block 5 never arrives
    blocks = []
    for index, k in enumerate(range(0, len(mic) // BLOCK * BLOCK, BLOCK)):
        if index != lost:
            blocks += echo.process(mic[k : k + BLOCK], T0 + k * BLOCK_NS // BLOCK, 0)
    assert echo.stats.mic_resyncs == 1
    assert abs(burst_onsets_s(blocks) - 0.6) <= 0.001  # after the loss, still on time
    # The audio captured after the gap starts a block stamped where it was captured.
    assert any(b.start_ns == T0 + (lost + 1) * BLOCK_NS for b in blocks)
    # Stamps jumping back (a restarted capture node) also restart the timeline.
    echo.process(_block(0), T0, 0)
    assert echo.stats.mic_resyncs == 2


@pytest.mark.unit
def test_mic_and_reference_at_other_rates_are_resampled_as_streams() -> None:
    """A 48 kHz mic and a 24 kHz reference in ragged blocks come out exactly as the one-shot
    resampling of each stream would (no clicks at block edges)."""
    config = EchoConfig(mode="aec", echo_guard=False)
    mic48 = speech_like(1.0, 48000, seed=4) // 4
    direct = EchoController(config)  # the same mic, resampled in one go, fed at 16 kHz
    mic16 = resample(mic48, 48000, RATE)
    expected = []
    for k in range(0, len(mic16) - BLOCK, BLOCK):
        expected += direct.process(mic16[k : k + BLOCK], T0 + k * BLOCK_NS // BLOCK, 0)
    streamed = EchoController(config)
    got = []
    for k in range(0, len(mic48) - 1500, 1500):  # 31.25 ms blocks: edges fall between samples
        got += streamed.process(mic48[k : k + 1500], T0 + k * 1_000_000_000 // 48000, 0, sample_rate=48000)
    n = min(sum(len(b.pcm) for b in expected), sum(len(b.pcm) for b in got))
    want = np.concatenate([b.pcm for b in expected])[:n].astype(np.int32)
    have = np.concatenate([b.pcm for b in got])[:n].astype(np.int32)
    assert got[0].start_ns == expected[0].start_ns == T0
    assert np.max(np.abs(want - have)) <= 8  # AEC3 of signals 1 LSB apart

    reference24 = speech_like(1.0, 24000, seed=5)
    for k in range(0, len(reference24), 733):
        streamed.add_reference(reference24[k : k + 733], 24000, 1, T0 + k * 1_000_000_000 // 24000)
    streamed.set_assistant_speaking(False, 0)  # the reply ended: the held-back tail goes in too
    whole = resample(reference24, 24000, RATE)
    laid = streamed.reference.read(T0, len(whole))
    assert np.max(np.abs(laid.astype(np.int32) - whole.astype(np.int32))) <= 1


@pytest.mark.unit
def test_bad_reference_or_mic_rates_are_refused() -> None:
    echo = EchoController(EchoConfig(mode="aec"))
    with pytest.raises(ValueError):
        echo.add_reference(np.ones(480, dtype=np.int16), 1000003, 1, T0)
    with pytest.raises(ValueError):
        echo.process(np.ones(480, dtype=np.int16), T0, 0, sample_rate=4294967291)
    with pytest.raises(ValueError):
        echo.add_reference(np.ones(481, dtype=np.int16), 16000, 2, T0)


@pytest.mark.unit
def test_aec_always_high_passes_so_there_is_no_switch_for_it() -> None:
    """AEC3 enforces WebRTC's high-pass filter; `aec_high_pass_filter: false` did nothing, so
    the parameter is gone rather than lying (the linear engine does not high-pass at all)."""
    assert "aec_high_pass_filter" not in {f.name for f in dataclasses.fields(EchoConfig)}
    rumble = np.rint(8000 * np.sin(2 * np.pi * 40 * np.arange(2 * RATE) / RATE)).astype(np.int16)
    echo = EchoController(EchoConfig(mode="aec", aec_engine="webrtc"))
    out = np.concatenate(
        [
            b.pcm
            for k in range(0, len(rumble), BLOCK)
            for b in echo.process(rumble[k : k + BLOCK], T0 + k * BLOCK_NS // BLOCK, 0)
        ]
    )
    assert energy_db(out[RATE:]) < energy_db(rumble[RATE:]) - 30.0


# The room of a robot whose speaker and mic share a body: ~70 ms device + air delay, a short
# reverberant tail; the robot's voice reaches its mic at -20 dBFS, louder than a user a metre
# away (-26 dBFS).
ROBOT_ROOM = Room(delay_ms=70, reverb_ms=120, reverb_gain=0.08)


def utterance_starts(talk: Conversation, config: EchoConfig, model: SileroModel) -> list[float]:
    """Run the echo controller and then the real Silero VAD on what it lets through, block by
    block as the graph does; return when (s) each utterance starts."""
    echo = EchoController(config)
    model.reset()
    detector = VoiceDetector(VadConfig(), model)
    starts = []
    echo.set_assistant_speaking(True, T0)
    for k in range(0, len(talk.mic) // BLOCK * BLOCK, BLOCK):
        start = T0 + k * BLOCK_NS // BLOCK
        echo.add_reference(talk.played[k : k + BLOCK], RATE, 1, start)
        for block in echo.process(talk.mic[k : k + BLOCK], start, start) + echo.drain():
            for event in detector.process(block.pcm, RATE, 1, block.start_ns):
                if isinstance(event, VoiceActivity) and event.active:
                    starts.append((event.time_ns - T0) / 1e9)
    return starts


@pytest.fixture(scope="module")
def silero() -> SileroModel:
    return SileroModel()


@pytest.mark.unit
def test_residual_echo_starts_no_utterance_while_only_the_robot_speaks(silero: SileroModel) -> None:
    talk = conversation(RATE, ROBOT_ROOM, echo_dbfs=-20.0)
    assert len(talk.mic) > 10 * RATE  # several seconds of the robot talking, from a cold AEC
    starts = utterance_starts(talk, EchoConfig(mode="aec"), silero)
    assert starts == [], f"residual echo started utterances at {starts} s"


@pytest.mark.unit
def test_a_user_talking_over_the_robot_starts_an_utterance(silero: SileroModel) -> None:
    talk = conversation(RATE, ROBOT_ROOM, echo_dbfs=-20.0, user_dbfs=-26.0, user_at_s=(3.0, 6.5, 10.0))
    starts = utterance_starts(talk, EchoConfig(mode="aec"), silero)
    for begin, end in talk.user_spans:
        assert any(begin - 0.1 <= s <= end for s in starts), f"no start for the user at {begin} s: {starts}"
    false_starts = [s for s in starts if not any(b - 0.1 <= s <= e + 0.3 for b, e in talk.user_spans)]
    assert false_starts == []
