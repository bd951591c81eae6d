"""Player: validation, resampling, played_ms, explicit end, interruption by name, supervision.

The engine is driven by an explicit clock (T0 + n * MS), so what was played when is exact; the
loop tests use the real thread and a WAV sink and assert what was played, never how fast
(latencies are measured in bench/bench_player.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from byc_testing import wait_for

from by_your_command.audio.pcm import read_wav, resample
from by_your_command.audio.player import (
    ChunkRejected,
    Cut,
    PlaybackEngine,
    PlaybackState,
    PlayBlock,
    PlayerConfig,
    PlayerLoop,
    VoiceChunk,
)
from by_your_command.audio.sinks import WavSink

RATE = 16000
MS = 1_000_000
T0 = 1_700_000_000 * 1_000_000_000
BLOCK = 320  # 20 ms at 16 kHz


def tone(seconds: float, rate: int, freq: float = 440.0) -> np.ndarray:
    t = np.arange(int(seconds * rate)) / rate
    return np.rint(8000 * np.sin(2 * np.pi * freq * t)).astype(np.int16)


def chunk(stream_id: str, pcm: np.ndarray, rate: int = RATE, **kwargs: Any) -> VoiceChunk:
    return VoiceChunk(stream_id, pcm, rate, **kwargs)


def engine(max_queue_s: float = 10.0) -> PlaybackEngine:
    return PlaybackEngine(RATE, BLOCK, int(max_queue_s * RATE))


def play_blocks(eng: PlaybackEngine, now: int, count: int | None = None) -> tuple[list[PlayBlock], int]:
    """Hand `count` blocks (all, if None) to an ideal sink back to back from `now`; (blocks, end)."""
    played: list[PlayBlock] = []
    while count is None or len(played) < count:
        block = eng.next_block()
        if block is None:
            break
        eng.commit(block, now)
        played.append(block)
        now += len(block.pcm) * 1_000_000_000 // RATE
    return played, now


@pytest.mark.unit
@pytest.mark.parametrize(
    "kwargs",
    [
        {"block_ms": 41},
        {"block_ms": 0},
        {"sink": "wav"},
        {"sink": "pipe"},
        {"sample_rate": 0},
        {"sample_rate": 1_000_003},
        {"max_chunk_ms": 0},
        {"max_pause_ms": 0},
        {"max_pause_ms": 10**9},
    ],
)
def test_bad_player_config_is_a_clear_error(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        PlayerConfig(**kwargs)  # type: ignore[arg-type]


@pytest.mark.unit
@pytest.mark.parametrize(
    ("rate", "channels", "samples", "reason"),
    [
        (4_294_967_291, 1, 480, "sample_rate"),
        (1_000_003, 1, 480, "sample_rate"),
        (0, 1, 480, "sample_rate"),
        (7_999, 1, 480, "sample_rate"),
        (44_101, 1, 480, "resample_ratio"),
        (RATE, 0, 480, "channels"),
        (RATE, 200, 400, "channels"),
        (RATE, 2, 481, "partial_frame"),
        (8_000, 1, 8_000 * 10 + 1, "too_long"),  # 10 s + 1 frame (max_chunk_ms 10000)
        (192_000, 8, 192_000 * 8 * 11, "too_long"),
    ],
)
def test_absurd_chunks_are_rejected_by_reason_and_playback_goes_on(
    rate: int, channels: int, samples: int, reason: str
) -> None:
    eng = engine(max_queue_s=30.0)
    with pytest.raises(ChunkRejected) as raised:
        eng.enqueue(chunk("bad", np.zeros(samples, dtype=np.int16), rate, channels=channels), T0)
    assert raised.value.reason == reason
    assert eng.stats.rejected == {reason: 1} and eng.stats.chunks == 0
    assert eng.next_block() is None  # nothing of it was queued
    eng.enqueue(chunk("good", tone(0.1, 24000), 24000, end_of_stream=True), T0)
    blocks, end = play_blocks(eng, T0)
    assert [b.stream_id for b in blocks] == ["good"] * 5
    assert eng.status(end).finished


@pytest.mark.unit
def test_an_oversized_stream_id_is_rejected() -> None:
    eng = engine()
    with pytest.raises(ChunkRejected) as raised:
        eng.enqueue(chunk("x" * 300, tone(0.02, RATE)), T0)
    assert raised.value.reason == "stream_id" and eng.stats.chunks_rejected == 1


@pytest.mark.unit
def test_engine_resamples_a_ragged_24k_reply_like_a_one_shot_resample() -> None:
    eng = engine()
    voice = tone(1.0, 24000, 300.0)
    rng = np.random.default_rng(0)
    pos = 0
    while pos < len(voice):  # ragged chunks, as agents send them
        size = int(rng.integers(50, 2000))
        eng.enqueue(chunk("r1", voice[pos : pos + size], 24000), T0)
        pos += size
    eng.enqueue(chunk("r1", np.zeros(0, dtype=np.int16), 24000, end_of_stream=True), T0)
    blocks, _ = play_blocks(eng, T0)
    assert all(len(b.pcm) <= BLOCK and b.stream_id == "r1" for b in blocks)
    played = np.concatenate([b.pcm for b in blocks]).astype(np.float64)
    whole = resample(voice, 24000, RATE).astype(np.float64)
    assert abs(len(played) - len(whole)) <= 1  # one second at 16 kHz, nothing lost at chunk edges
    n = min(len(played), len(whole))
    assert np.abs(played[:n] - whole[:n]).max() <= 40  # of 8000 peak: no clicks at chunk edges


@pytest.mark.unit
def test_played_ms_counts_only_audio_that_has_played() -> None:
    eng = engine()
    eng.enqueue(chunk("r1", tone(0.5, RATE)), T0)
    _, now = play_blocks(eng, T0, count=10)  # 10 blocks of 20 ms, back to back
    mid = eng.status(now - 10 * MS)  # halfway through the 10th block
    assert mid.stream_id == "r1" and mid.speaking
    assert (mid.played_ms, mid.queued_ms) == (190, 300)
    done = eng.status(now)
    assert done.played_ms == 200 and not done.finished and not done.starved  # 300 ms still queued


@pytest.mark.unit
def test_finished_only_at_end_of_stream_and_running_dry_before_it_is_starved() -> None:
    eng = engine()
    eng.enqueue(chunk("r1", tone(0.04, RATE)), T0)
    _, now = play_blocks(eng, T0)
    assert eng.speaking(now - 1)
    dry = eng.status(now)
    assert (dry.played_ms, dry.speaking, dry.finished, dry.starved) == (40, False, False, True)
    eng.enqueue(chunk("r1", tone(0.02, RATE)), now)  # the late chunk: the same reply goes on
    eng.enqueue(chunk("r1", np.zeros(0, dtype=np.int16), end_of_stream=True), now)  # empty end marker
    blocks, end = play_blocks(eng, now + 30 * MS)
    assert [b.stream_id for b in blocks] == ["r1"]
    assert eng.status(end - 1) == PlaybackState("r1", 59, 0, True, False, False, False)
    assert eng.status(end) == PlaybackState("r1", 60, 0, False, True, False, False)


@pytest.mark.unit
def test_a_reply_without_end_of_stream_never_reports_finished() -> None:
    eng = engine()
    eng.enqueue(chunk("old-producer", tone(0.1, RATE)), T0)
    _, end = play_blocks(eng, T0)
    state = eng.status(end + 60_000 * MS)
    assert (state.played_ms, state.finished, state.starved) == (100, False, True)


@pytest.mark.unit
def test_chunks_after_end_of_stream_are_dropped_and_counted() -> None:
    eng = engine()
    eng.enqueue(chunk("r1", tone(0.04, RATE), end_of_stream=True), T0)
    eng.enqueue(chunk("r1", tone(0.04, RATE)), T0)
    blocks, _ = play_blocks(eng, T0)
    assert len(blocks) == 2 and eng.stats.chunks_dropped_closed == 1


@pytest.mark.unit
def test_the_next_reply_survives_an_interruption_that_names_the_previous_one() -> None:
    """B's first chunk arrives before the interruption meant for A: A is cut, B plays whole."""
    eng = engine()
    eng.enqueue(chunk("A", tone(1.0, RATE)), T0)
    _, now = play_blocks(eng, T0, count=5)
    eng.enqueue(chunk("B", tone(0.2, RATE, 330.0)), now)
    outcome = eng.interrupt(Cut("A", reason="barge_in"), now - 10 * MS)  # mid 5th block
    assert [s.stream_id for s in outcome.cut] == ["A"] and outcome.flush_sink
    assert outcome.cut[0].interrupted and outcome.cut[0].played_ms == 90
    eng.enqueue(chunk("A", tone(0.1, RATE)), now)  # A's tail, still in flight from the agent
    eng.enqueue(chunk("B", tone(0.1, RATE, 330.0), end_of_stream=True), now)
    blocks, end = play_blocks(eng, now)
    assert {b.stream_id for b in blocks} == {"B"}
    assert sum(len(b.pcm) for b in blocks) == int(0.3 * RATE)
    assert eng.stats.chunks_dropped_interrupted == 1
    assert eng.status(end) == PlaybackState("B", 300, 0, False, True, False, False)


@pytest.mark.unit
def test_an_interruption_for_a_reply_not_yet_arrived_drops_it() -> None:
    eng = engine()
    eng.interrupt(Cut("C"), T0)
    eng.enqueue(chunk("C", tone(0.1, RATE)), T0 + MS)
    assert eng.next_block() is None and eng.stats.chunks_dropped_interrupted == 1


@pytest.mark.unit
def test_a_blanket_cut_takes_replies_stamped_up_to_it_and_keeps_later_ones() -> None:
    eng = engine()
    eng.enqueue(chunk("A", tone(0.5, RATE), stamp_ns=T0), T0)
    _, now = play_blocks(eng, T0, count=2)
    eng.enqueue(chunk("B", tone(0.1, RATE), stamp_ns=now + 5 * MS), now)
    outcome = eng.interrupt(Cut("", up_to_ns=now + 2 * MS), now)
    assert [s.stream_id for s in outcome.cut] == ["A"]
    # A reply stamped before the cut but arriving after it was part of what the agent cut.
    eng.enqueue(chunk("late", tone(0.1, RATE), stamp_ns=now + 1 * MS), now)
    blocks, _ = play_blocks(eng, now)
    assert {b.stream_id for b in blocks} == {"B"} and eng.stats.chunks_dropped_interrupted == 1


@pytest.mark.unit
def test_an_unstamped_cut_takes_everything_held_now() -> None:
    eng = engine()
    eng.enqueue(chunk("A", tone(0.1, RATE)), T0)
    eng.enqueue(chunk("", tone(0.1, RATE)), T0)
    outcome = eng.interrupt(Cut(), T0)
    assert sorted(s.stream_id for s in outcome.cut) == ["", "A"] and not outcome.flush_sink
    assert eng.next_block() is None and not eng.speaking(T0)
    eng.enqueue(chunk("", tone(0.02, RATE)), T0 + MS)  # an empty id is never blocked
    assert (block := eng.next_block()) is not None and block.stream_id == ""


@pytest.mark.unit
def test_interruption_freezes_played_ms_and_speaking_goes_false_at_once() -> None:
    eng = engine()
    eng.enqueue(chunk("r1", tone(1.0, RATE)), T0)
    _, now = play_blocks(eng, T0, count=10)  # 200 ms handed to the sink; the 10th plays till `now`
    cut_at = now - 15 * MS
    outcome = eng.interrupt(Cut("r1"), cut_at)
    assert outcome.flush_sink
    state = eng.status(cut_at)
    assert state == PlaybackState("r1", 185, 0, False, False, True, False)
    assert outcome.cut == (state,)
    assert eng.status(now + 1000 * MS) == state  # time passes: nothing more was heard
    assert eng.stats.interruptions == 1 and eng.stats.streams_cut == 1


@pytest.mark.unit
def test_cutting_a_finished_reply_changes_nothing() -> None:
    eng = engine()
    eng.enqueue(chunk("r1", tone(0.04, RATE), end_of_stream=True), T0)
    _, end = play_blocks(eng, T0)
    assert eng.interrupt(Cut("r1"), end).cut == ()
    assert eng.status(end).finished and eng.stats.interruptions == 0


@pytest.mark.unit
def test_a_flushed_device_returns_the_kept_replys_blocks_to_its_queue() -> None:
    """A device holds several blocks: A's last and B's first. Cutting A drops B's too, so B's
    unplayed block goes back to B's queue and nothing of B is lost."""
    eng = engine()
    eng.enqueue(chunk("A", tone(0.02, RATE), end_of_stream=True), T0)
    eng.enqueue(chunk("B", tone(0.04, RATE, 330.0), end_of_stream=True), T0)
    a = eng.next_block()
    assert a is not None
    eng.commit(a, T0)
    b = eng.next_block()
    assert b is not None and b.stream_id == "B"
    eng.commit(b, T0 + 20 * MS)
    outcome = eng.interrupt(Cut("A"), T0 + 5 * MS)
    assert outcome.flush_sink and outcome.cut[0].played_ms == 5
    again = eng.next_block()
    assert again is not None and again.stream_id == "B" and np.array_equal(again.pcm, b.pcm)


@pytest.mark.unit
def test_responses_play_in_order() -> None:
    eng = PlaybackEngine(RATE, 800, RATE)
    eng.enqueue(chunk("a", tone(0.05, RATE), end_of_stream=True), T0)
    eng.enqueue(chunk("b", tone(0.05, RATE), end_of_stream=True), T0)
    blocks, _ = play_blocks(eng, T0)
    assert [b.stream_id for b in blocks] == ["a", "b"]


@pytest.mark.unit
def test_a_reply_followed_at_once_by_the_next_still_reports_its_end() -> None:
    """The status follows the reply playing: back to back, the first one's `finished` was never
    published, and a listener waiting for it (the demo) waited for ever."""
    eng = engine()
    eng.enqueue(chunk("a", tone(0.04, RATE), end_of_stream=True), T0)
    eng.enqueue(chunk("b", tone(0.04, RATE), end_of_stream=True), T0)
    _, end = play_blocks(eng, T0)
    assert eng.status(end).stream_id == "b"
    [retired] = eng.take_retired(end)
    assert (retired.stream_id, retired.finished, retired.played_ms) == ("a", True, 40)
    assert eng.take_retired(end) == ()  # once
    # one whose end was reported while it was the current reply is not reported again
    eng.enqueue(chunk("c", tone(0.04, RATE), end_of_stream=True), end)
    _, later = play_blocks(eng, end + 100 * MS)
    assert eng.status(later).finished  # "c" reported finished...
    eng.enqueue(chunk("d", tone(0.04, RATE), end_of_stream=True), later)
    play_blocks(eng, later + 100 * MS)
    assert eng.take_retired(later + 1000 * MS) == ()  # ...and "b" was, when it was the current one


@pytest.mark.unit
def test_queue_overflow_is_counted() -> None:
    eng = engine(max_queue_s=0.1)
    eng.enqueue(chunk("r", tone(0.5, RATE)), T0)
    assert eng.stats.samples_dropped_overflow == int(0.4 * RATE)


@pytest.mark.unit
def test_a_pause_holds_the_reply_and_a_resume_goes_on_where_it_stopped() -> None:
    """Issue 34: a barge-in being judged pauses the reply; played_ms stays continuous, so a later
    real interruption reports what was heard of the whole reply."""
    eng = engine()
    eng.enqueue(chunk("r1", tone(1.0, RATE), end_of_stream=True), T0)
    eng.enqueue(chunk("r2", tone(0.1, RATE), end_of_stream=True), T0)
    _, now = play_blocks(eng, T0, count=10)
    pause_at = now - 15 * MS  # the 10th block has played 5 ms of its 20
    state, flush = eng.pause("r1", pause_at)
    assert flush and state is not None and state.paused and not state.speaking
    assert state.played_ms == 185 and state.queued_ms == 815
    assert eng.next_block() is None  # nothing plays, not even the reply behind it
    assert eng.status(pause_at + 3000 * MS).played_ms == 185
    resumed = eng.resume("r1", pause_at + 3000 * MS)
    assert resumed is not None and not resumed.paused
    block = eng.next_block()
    assert block is not None and block.stream_id == "r1"
    assert np.array_equal(block.pcm, tone(1.0, RATE)[185 * 16 : 185 * 16 + BLOCK])  # from the pause on
    eng.commit(block, pause_at + 3000 * MS)
    _, later = play_blocks(eng, pause_at + 3020 * MS, count=5)
    outcome = eng.interrupt(Cut("r1"), later)
    assert outcome.cut[0].played_ms == 185 + 6 * 20  # what was heard of the whole reply
    assert [b.stream_id for b in play_blocks(eng, later)[0]][:1] == ["r2"]
    assert (eng.stats.pauses, eng.stats.resumes) == (1, 1)


@pytest.mark.unit
def test_pausing_what_is_not_playing_changes_nothing() -> None:
    eng = engine()
    eng.enqueue(chunk("r1", tone(0.04, RATE), end_of_stream=True), T0)
    _, end = play_blocks(eng, T0)
    assert eng.pause("r1", end) == (eng.status(end), False)  # finished: nothing to hold
    assert eng.pause("nobody", end) == (None, False)
    assert eng.resume("r1", end) is None and eng.stats.pauses == 0


@pytest.mark.unit
def test_a_pause_nobody_resolves_becomes_a_cut() -> None:
    eng = engine()
    eng.enqueue(chunk("r1", tone(1.0, RATE)), T0)
    play_blocks(eng, T0, count=5)
    eng.pause("r1", T0 + 100 * MS)
    assert eng.pause_deadline_ns(500 * MS) == T0 + 600 * MS
    assert eng.expire_pauses(500 * MS, T0 + 600 * MS).cut == ()
    outcome = eng.expire_pauses(500 * MS, T0 + 601 * MS)
    assert [s.stream_id for s in outcome.cut] == ["r1"] and outcome.cut[0].interrupted
    assert eng.stats.pauses_expired == 1 and eng.pause_deadline_ns(500 * MS) is None


# -- the real loop, with a WAV sink --------------------------------------------------------


class Recorder:
    def __init__(self, loop_engine: PlaybackEngine) -> None:
        self.engine = loop_engine
        self.played: list[tuple[PlayBlock, int]] = []
        self.states: list[PlaybackState] = []
        self.errors: list[BaseException] = []

    def on_played(self, block: PlayBlock, start_ns: int) -> None:
        self.played.append((block, start_ns))

    def on_change(self) -> None:
        self.states.append(self.engine.status(loop_clock()))

    def on_error(self, error: BaseException) -> None:
        self.errors.append(error)


loop_clock = time.time_ns


def make_loop(
    tmp_path: Path,
    realtime: bool,
    sink: Any = None,
    on_played: Callable[[PlayBlock, int], None] | None = None,
) -> tuple[PlayerLoop, Recorder, WavSink]:
    eng = PlaybackEngine(RATE, BLOCK, 60 * RATE)
    wav = sink.inner if sink is not None else WavSink(tmp_path / "out.wav", RATE, realtime=realtime)
    recorder = Recorder(eng)
    loop = PlayerLoop(
        eng,
        sink or wav,
        on_played or recorder.on_played,
        recorder.on_change,
        on_error=recorder.on_error,
    )
    return loop, recorder, wav


@pytest.mark.unit
def test_loop_drains_to_the_wav_sink_without_realtime(tmp_path: Path) -> None:
    loop, recorder, sink = make_loop(tmp_path, realtime=False)
    loop.start()
    loop.engine.enqueue(chunk("r1", tone(0.5, 24000), 24000, end_of_stream=True), loop_clock())
    loop.wake()
    wait_for(lambda: sink.samples_written >= RATE // 2, timeout=5, what="the response written")
    loop.stop()
    pcm, rate, channels = read_wav(tmp_path / "out.wav")
    assert (rate, channels, len(pcm)) == (RATE, 1, RATE // 2)
    assert all(len(b.pcm) <= BLOCK for b, _ in recorder.played)


@pytest.mark.unit
def test_a_realtime_interruption_leaves_exactly_played_ms_in_the_wav_and_the_next_reply_whole(
    tmp_path: Path,
) -> None:
    loop, recorder, _ = make_loop(tmp_path, realtime=True)
    loop.start()
    first = tone(3.0, RATE)
    loop.engine.enqueue(chunk("A", first), loop_clock())
    loop.wake()
    wait_for(lambda: len(recorder.played) >= 10, timeout=5, what="200 ms of A played")
    loop.engine.enqueue(chunk("B", tone(0.2, RATE, 330.0), end_of_stream=True), loop_clock())
    outcome = loop.interrupt(Cut("A", reason="barge_in"))
    assert [s.stream_id for s in outcome.cut] == ["A"]
    cut_state = outcome.cut[0]
    assert cut_state.interrupted and 180 <= cut_state.played_ms < 3000  # 9 blocks heard at least
    wait_for(lambda: any(s.stream_id == "B" and s.finished for s in recorder.states), timeout=5, what="B")
    assert loop.engine.status(loop_clock()).speaking is False
    loop.stop()
    pcm, _, _ = read_wav(tmp_path / "out.wav")
    heard_a = cut_state.played_ms * RATE // 1000
    # The file is what a listener heard: A up to the cut (to the sample played_ms stands for),
    # then all of B; nothing of A after the cut.
    assert len(pcm) - int(0.2 * RATE) in range(heard_a, heard_a + RATE // 1000)
    assert np.array_equal(pcm[:heard_a], first[:heard_a])
    assert loop.engine.status(loop_clock()).played_ms == 200  # B's status at the end


@pytest.mark.unit
def test_a_paused_then_resumed_reply_is_heard_whole_in_the_wav(tmp_path: Path) -> None:
    """Through the real loop and a real-time sink: what the listener hears is the reply once,
    exactly, however often it is paused (the block in the sink at a pause is played again from
    its unheard part only, and a block handed out meanwhile goes after it)."""
    loop, recorder, _ = make_loop(tmp_path, realtime=True)
    loop.start()
    reply = np.random.default_rng(3).normal(0, 3000, RATE).astype(np.int16)
    loop.engine.enqueue(chunk("A", reply, end_of_stream=True), loop_clock())
    loop.wake()
    for pause in range(1, 6):
        due = 7 * pause  # blocks played before this pause
        wait_for(lambda due=due: len(recorder.played) >= due, timeout=5, what=f"pause {pause} due")
        paused = loop.pause("A")
        assert paused is not None and paused.paused
        assert loop.resume("A") is not None
    wait_for(lambda: any(s.stream_id == "A" and s.finished for s in recorder.states), timeout=5, what="A")
    loop.stop()
    pcm, _, _ = read_wav(tmp_path / "out.wav")
    assert np.array_equal(pcm, reply)
    assert recorder.states[-1].played_ms == 1000 and loop.engine.stats.pauses == 5


@pytest.mark.unit
def test_loop_reports_speaking_then_finished_in_order(tmp_path: Path) -> None:
    loop, recorder, _ = make_loop(tmp_path, realtime=True)
    loop.start()
    loop.engine.enqueue(chunk("r1", tone(0.1, RATE), end_of_stream=True), loop_clock())
    loop.wake()
    wait_for(lambda: recorder.states and recorder.states[-1].finished, timeout=5, what="r1 finished")
    loop.stop()
    flags = [(s.stream_id, s.speaking, s.finished) for s in recorder.states if s.stream_id == "r1"]
    assert flags == [("r1", True, False), ("r1", False, True)]
    assert recorder.states[-1].played_ms == 100


class FlakySink:
    """A WAV sink whose play raises on the given calls (a device error, an odd driver)."""

    def __init__(self, inner: WavSink, fail_on: set[int]) -> None:
        self.inner = inner
        self.sample_rate = inner.sample_rate
        self.calls = 0
        self.fail_on = fail_on

    def play(self, pcm: np.ndarray, cancel: threading.Event) -> int | None:
        self.calls += 1
        if self.calls in self.fail_on:
            raise OSError("device went away")
        return self.inner.play(pcm, cancel)

    def flush(self, at_ns: int) -> None:
        self.inner.flush(at_ns)

    def close(self) -> None:
        self.inner.close()


@pytest.mark.unit
def test_the_loop_survives_a_failing_sink_and_callbacks(tmp_path: Path) -> None:
    played_calls = 0

    def on_played(block: PlayBlock, start_ns: int) -> None:  # the node's publish, failing once
        nonlocal played_calls
        played_calls += 1
        if played_calls == 3:
            raise RuntimeError("publish failed at shutdown")

    flaky = FlakySink(WavSink(tmp_path / "out.wav", RATE, realtime=False), fail_on={2})
    loop, recorder, wav = make_loop(tmp_path, realtime=False, sink=flaky, on_played=on_played)
    loop.start()
    loop.engine.enqueue(chunk("r1", tone(0.2, RATE), end_of_stream=True), loop_clock())
    loop.wake()
    wait_for(lambda: recorder.states and recorder.states[-1].finished, timeout=5, what="r1 finished")
    loop.stop()
    assert loop.errors == 2 and [type(e) for e in recorder.errors] == [OSError, RuntimeError]
    assert loop.engine.stats.blocks_failed == 1  # the block in the sink's hand when it failed
    assert loop.engine.stats.blocks_played == 9  # the other nine of ten were played
    assert wav.samples_written == 9 * BLOCK


@pytest.mark.unit
def test_stop_cuts_what_is_playing_and_leaves_speaking_false(tmp_path: Path) -> None:
    loop, recorder, _ = make_loop(tmp_path, realtime=True)
    loop.start()
    loop.engine.enqueue(chunk("r1", tone(3.0, RATE)), loop_clock())
    loop.wake()
    wait_for(lambda: len(recorder.played) >= 3, timeout=5, what="r1 playing")  # 2 blocks heard at least
    outcome = loop.stop()
    assert [s.stream_id for s in outcome.cut] == ["r1"]
    state = loop.engine.status(loop_clock())
    assert state.interrupted and not state.speaking
    pcm, _, _ = read_wav(tmp_path / "out.wav")
    heard = state.played_ms * RATE // 1000
    assert 40 <= state.played_ms < 3000 and len(pcm) in range(heard, heard + RATE // 1000)
