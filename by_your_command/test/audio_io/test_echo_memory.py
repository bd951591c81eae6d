"""The learned echo path kept across restarts (audio/echo_memory.py): a canceller started from
what an earlier one learned in the same room cancels the robot's first words, where a new one
is still learning; one from another room is dropped within its trial; a file that is not a
usable echo path is refused with its reason and the canceller starts new."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
from audio_io.synthetic_room import ROBOT_REPLY, Room, at_level, energy_db, espeak, recorded_speech

from by_your_command.audio import echo_memory
from by_your_command.audio.echo import EchoConfig, EchoController
from by_your_command.audio.pcm import Int16Array

pytestmark = pytest.mark.unit

RATE = 16000
BLOCK = 512
T0 = 1_700_000_000 * 1_000_000_000
# The canceller's own output (no residual suppressor), so what is measured is the echo path.
CONFIG = EchoConfig(mode="aec", echo_guard=False)
ROOM = Room(delay_ms=120)  # 0.6 s of response: a new filter needs seconds of speech for it
SHAPE = (80, 161)  # 800 ms of 10 ms partitions at 16 kHz


def run(echo: EchoController, played: Int16Array, mic: Int16Array) -> Int16Array:
    """The controller's output for `mic` while `played` plays (the robot speaking throughout)."""
    echo.set_assistant_speaking(True, T0)
    out = []
    for k in range(0, len(mic) // BLOCK * BLOCK, BLOCK):
        start = T0 + k * 1_000_000_000 // RATE
        echo.add_reference(played[k : k + BLOCK], RATE, 1, start)
        out += [block.pcm for block in echo.process(mic[k : k + BLOCK], start, start) + echo.drain()]
    return np.concatenate(out)


def first_second_reduction_db(mic: Int16Array, out: Int16Array) -> float:
    return energy_db(mic[:RATE]) - energy_db(out[:RATE])


@pytest.fixture(scope="module")
def remembered(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The echo path a canceller kept after 20 s of the robot's voice in ROOM."""
    file = tmp_path_factory.mktemp("memory") / "echo_path.npz"
    earlier = recorded_speech(20.0, RATE)
    echo = EchoController(CONFIG)
    run(echo, earlier, ROOM.echo(earlier, RATE))
    kept = echo_memory.keep(echo, file)
    assert kept is not None and kept.ok, kept
    return file


@pytest.fixture(scope="module")
def reply() -> Int16Array:
    return at_level(espeak(ROBOT_REPLY, "en-gb", RATE), -18.0)  # not what the path was learned on


def test_a_remembered_path_cancels_the_first_reply_from_its_start(
    remembered: Path, reply: Int16Array
) -> None:
    mic = ROOM.echo(reply, RATE)
    new = first_second_reduction_db(mic, run(EchoController(CONFIG), reply, mic))
    echo = EchoController(CONFIG)
    restored = echo_memory.restore(echo, remembered)
    assert restored.ok and "starting from" in restored.message
    started = first_second_reduction_db(mic, run(echo, reply, mic))
    assert new < 8.0  # the cold start this is about
    assert started > new + 10.0
    assert echo.stats.remembered_dropped == 0


def test_another_rooms_path_is_dropped_and_learning_starts_new(remembered: Path, reply: Int16Array) -> None:
    other_room = Room(delay_ms=200, gain=0.5, reverb_ms=200, reverb_gain=0.2)
    mic = other_room.echo(reply, RATE)
    echo = EchoController(CONFIG)
    assert echo_memory.restore(echo, remembered).ok
    out = run(echo, reply, mic)
    assert echo.stats.remembered_dropped == 1
    new = run(EchoController(CONFIG), reply, mic)
    later = slice(4 * RATE, 8 * RATE)  # once learned: as good as a canceller that started new
    assert energy_db(mic[later]) - energy_db(out[later]) > energy_db(mic[later]) - energy_db(new[later]) - 3.0


def test_a_moved_robot_keeps_its_bodys_path_and_relearns_the_room(
    remembered: Path, reply: Int16Array
) -> None:
    # The same direct path, another reverberant tail: the output stays under the mic (not
    # dropped), but leaves far more than the echo remembered; sure of itself, the canceller took
    # that for double talk and kept the wrong tail. Checked in its trial, it relearns the room.
    moved = Room(delay_ms=120).echo(reply, RATE, seed=3)  # ROOM's direct path, another tail
    echo = EchoController(CONFIG)
    assert echo_memory.restore(echo, remembered).ok
    out = run(echo, reply, moved)
    assert (echo.stats.remembered_relearned, echo.stats.remembered_dropped) == (1, 0)
    new = run(EchoController(CONFIG), reply, moved)
    later = slice(4 * RATE, 8 * RATE)
    assert (
        energy_db(moved[later]) - energy_db(out[later])
        > energy_db(moved[later]) - energy_db(new[later]) - 3.0
    )
    same = EchoController(CONFIG)
    assert echo_memory.restore(same, remembered).ok
    run(same, reply, ROOM.echo(reply, RATE))
    assert (same.stats.remembered_relearned, same.stats.remembered_dropped) == (0, 0)


def test_nothing_is_kept_before_the_canceller_has_learned(tmp_path: Path) -> None:
    echo = EchoController(CONFIG)
    short = recorded_speech(0.5, RATE)
    run(echo, short, ROOM.echo(short, RATE))
    assert echo_memory.keep(echo, tmp_path / "echo_path.npz") is None
    assert not (tmp_path / "echo_path.npz").exists()


def test_a_directory_that_cannot_be_written_is_reported_not_raised(remembered: Path, tmp_path: Path) -> None:
    echo = EchoController(CONFIG)
    assert echo_memory.restore(echo, remembered).ok
    learned = recorded_speech(8.0, RATE)
    run(echo, learned, ROOM.echo(learned, RATE))  # its trial over: worth keeping again
    assert echo.learned_echo() is not None
    blocked = tmp_path / "a_file"
    blocked.write_text("")
    kept = echo_memory.keep(echo, blocked / "echo_path.npz")
    assert kept is not None and not kept.ok and "could not remember" in kept.message


def test_a_missing_file_is_a_new_start() -> None:
    echo = EchoController(CONFIG)
    outcome = echo_memory.restore(echo, Path("/nonexistent/echo_path.npz"))
    assert outcome.ok and "learning it from the first reply" in outcome.message


def _npz(**arrays: object) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]
    return buffer.getvalue()


def _good(**override: object) -> dict[str, object]:
    arrays: dict[str, object] = {
        "format": np.int64(1),
        "sample_rate": np.int64(RATE),
        "coefficients": np.zeros(SHAPE, dtype=np.complex128),
        "variances": np.full(SHAPE, 0.001),
        "echo_left_db": np.float64(-20.0),
        "residual_db": np.zeros(16),
        "coupling_db": np.zeros(16),
    }
    arrays.update(override)
    return arrays


def _huge_header() -> bytes:
    """An .npy member whose header claims 10^12 coefficients over 16 bytes of data."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        header, {"descr": "<c16", "fortran_order": False, "shape": (10**10, 100)}
    )
    member = header.getvalue() + b"\x00" * 16
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for key, value in _good().items():
            archive.writestr(f"{key}.npy", member if key == "coefficients" else _npy(value))
    return buffer.getvalue()


def _npy(value: object) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, value)
    return buffer.getvalue()


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b"not an archive", "not an echo path file"),
        (_npz(**_good(), extra=np.zeros(3)), "an echo path file holds"),
        (_npz(**_good(format=np.int64(2))), "format 2"),
        (_npz(**_good(sample_rate=np.int64(48000))), "48000 Hz"),
        (_npz(**_good(sample_rate=np.float64(16000.0))), "sample_rate is float64"),
        (_npz(**_good(coefficients=np.zeros((40, 161), dtype=np.complex128))), "another aec_filter_ms"),
        (_npz(**_good(coefficients=np.zeros(SHAPE, dtype=object))), "coefficients is object"),
        (_npz(**_good(coefficients=np.full(SHAPE, np.nan, dtype=np.complex128))), "coefficients has values"),
        (_npz(**_good(coefficients=np.full(SHAPE, 1e6, dtype=np.complex128))), "not an echo path"),
        (_npz(**_good(variances=np.full(SHAPE, -1.0))), "variances outside"),
        (_npz(**_good(echo_left_db=np.float64(np.inf))), "echo_left_db has values that are not finite"),
        (_npz(**_good(coupling_db=np.full(16, 1e9))), "coupling_db outside"),
        (_npz(**_good(residual_db=np.zeros(8))), "residual_db is float64 (8,)"),
        (_huge_header(), "coefficients is complex128 (10000000000, 100)"),
        (_npz(**_good())[:-200], "not an echo path file"),
    ],
    ids=[
        "not_zip",
        "extra_member",
        "format",
        "rate",
        "rate_type",
        "filter_length",
        "pickled_objects",
        "nan",
        "absurd_gain",
        "negative_variance",
        "infinite_level",
        "absurd_coupling",
        "other_band_count",
        "huge_claimed_shape",
        "cut_short",
    ],
)
def test_a_file_that_is_no_usable_echo_path_is_refused_with_its_reason(
    tmp_path: Path, content: bytes, reason: str
) -> None:
    file = tmp_path / "echo_path.npz"
    file.write_bytes(content)
    echo = EchoController(CONFIG)
    outcome = echo_memory.restore(echo, file)
    assert not outcome.ok
    assert reason in outcome.message
    assert echo.learned_echo() is None  # started new: nothing of the file taken


def test_an_oversized_file_is_refused_unread(tmp_path: Path) -> None:
    file = tmp_path / "echo_path.npz"
    with file.open("wb") as out:
        out.truncate(echo_memory.MAX_FILE_BYTES + 1)  # sparse: nothing written
    outcome = echo_memory.restore(EchoController(CONFIG), file)
    assert not outcome.ok and "more than an echo path takes" in outcome.message


def test_where_the_path_is_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_STATE_HOME", "/state")
    assert echo_memory.memory_file("auto", "/robot1/echo_suppressor") == Path(
        "/state/by_your_command/echo_path/robot1.echo_suppressor.npz"
    )
    assert echo_memory.memory_file("none", "/echo_suppressor") is None
    assert echo_memory.memory_file("/tmp/x.npz", "/echo_suppressor") == Path("/tmp/x.npz")
    with pytest.raises(ValueError, match="auto, none or a file path"):
        EchoConfig(mode="aec", aec_echo_memory=" ")


def test_without_a_linear_canceller_there_is_nothing_to_remember(remembered: Path) -> None:
    for config in (EchoConfig(mode="gate"), EchoConfig(mode="aec", aec_engine="webrtc")):
        echo = EchoController(config)
        assert echo.echo_path_shape is None
        assert echo_memory.restore(echo, remembered).message.startswith("no linear canceller")
