"""What the linear echo canceller learned of the room, kept in a file across restarts.

A new canceller needs seconds of the robot's voice before it cancels well (1-5 dB in the first
2 s of a reverberant room), and its residual suppressor starts strict meanwhile: a user talking
over the first reply after a start was taken down with the echo and heard late, and a "stop"
said in its first seconds was mostly missed. The speaker-to-mic path of a robot changes little
between runs, so a node keeps what its canceller learned (the output filter, its variances, the
echo it leaves, the suppressor's shares; at the end of each reply and at shutdown) and starts
from it: a restart is as if the node had kept running, and a room that changed meanwhile is
followed as when the robot moves while it runs. The file is input like any other: one that is
not ours, of another rate or filter length, or with absurd values is refused with the reason,
and the canceller starts new. One that loads but belongs to another room is dropped by the
canceller itself (audio/echo_linear.py: it is on trial for its first seconds).
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from by_your_command.audio.echo import EchoController
from by_your_command.audio.echo_linear import RESIDUAL_BANDS, LearnedEcho
from by_your_command.audio.recording import ensure_private_dir, state_dir

FORMAT = 1
MAX_FILE_BYTES = 16 * 1024 * 1024  # the longest filter (2 s at 48 kHz) takes 2.3 MB
# |coefficient| is a partition's gain at one frequency: 100 is an echo 40 dB over what played.
MAX_COEFFICIENT = 100.0
MAX_VARIANCE = 1.0  # a coefficient's variance: a new one's is 0.006
DB_RANGE = (-200.0, 60.0)  # the learned levels (echo left, the suppressor's shares)


def default_file(node_name: str) -> Path:
    """$XDG_STATE_HOME/by_your_command/echo_path/<node's full name>.npz (~/.local/state/... when
    unset): one file per node, so two robots' nodes on one machine keep their own."""
    name = node_name.strip("/").replace("/", ".") or "echo"
    return state_dir() / "echo_path" / f"{name}.npz"


def memory_file(setting: str, node_name: str) -> Path | None:
    """The file for an `aec_echo_memory` setting: auto, none or a path."""
    if setting == "none":
        return None
    if setting == "auto":
        return default_file(node_name)
    return Path(setting).expanduser()


def load(file: Path, sample_rate: int, shape: tuple[int, int]) -> LearnedEcho:
    """What a canceller at `sample_rate` with an echo path of `shape` learned, kept in `file`.
    Raises FileNotFoundError if there is none, ValueError (with the reason) if it is not usable."""
    size = file.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ValueError(f"{size} bytes, more than an echo path takes ({MAX_FILE_BYTES})")
    bands = (RESIDUAL_BANDS,)
    expected = {
        "format": ((), np.dtype(np.int64)),
        "sample_rate": ((), np.dtype(np.int64)),
        "coefficients": (shape, np.dtype(np.complex128)),
        "variances": (shape, np.dtype(np.float64)),
        "echo_left_db": ((), np.dtype(np.float64)),
        "residual_db": (bands, np.dtype(np.float64)),
        "coupling_db": (bands, np.dtype(np.float64)),
    }
    try:
        with zipfile.ZipFile(file) as archive:
            names = {info.filename for info in archive.infolist()}
            if names != {f"{key}.npy" for key in expected}:
                raise ValueError(f"holds {sorted(names)}, an echo path file holds {sorted(expected)}")
            version = int(_read(archive, "format", *expected["format"]))
            if version != FORMAT:
                raise ValueError(f"format {version}, this version reads format {FORMAT}")
            rate = int(_read(archive, "sample_rate", *expected["sample_rate"]))
            if rate != sample_rate:
                raise ValueError(f"learned at {rate} Hz, the canceller runs at {sample_rate} Hz")
            arrays = {key: _read(archive, key, *expected[key]) for key in list(expected)[2:]}
    except (zipfile.BadZipFile, EOFError) as error:
        raise ValueError(f"not an echo path file ({error})") from None
    for key, array in arrays.items():
        if not np.all(np.isfinite(array)):
            raise ValueError(f"{key} has values that are not finite")
    if float(np.max(np.abs(arrays["coefficients"]), initial=0.0)) > MAX_COEFFICIENT:
        raise ValueError(f"a gain over {MAX_COEFFICIENT:g}: not an echo path")
    variances = arrays["variances"]
    if float(np.min(variances, initial=0.0)) < 0.0 or float(np.max(variances, initial=0.0)) > MAX_VARIANCE:
        raise ValueError(f"variances outside [0, {MAX_VARIANCE:g}]")
    low, high = DB_RANGE
    for key in ("echo_left_db", "residual_db", "coupling_db"):
        if np.any(arrays[key] < low) or np.any(arrays[key] > high):
            raise ValueError(f"{key} outside [{low:g}, {high:g}] dB")
    return LearnedEcho(
        arrays["coefficients"],
        arrays["variances"],
        float(arrays["echo_left_db"]),
        arrays["residual_db"],
        arrays["coupling_db"],
    )


def _read(archive: zipfile.ZipFile, key: str, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    """One array of the file, its header checked before anything is read or allocated (a
    header may claim any shape; numpy's own reader would allocate it)."""
    with archive.open(f"{key}.npy") as member:
        version = np.lib.format.read_magic(member)
        if version == (1, 0):
            found_shape, fortran, found_dtype = np.lib.format.read_array_header_1_0(member)
        elif version == (2, 0):
            found_shape, fortran, found_dtype = np.lib.format.read_array_header_2_0(member)
        else:
            raise ValueError(f"{key}: .npy version {version} not read")
        if found_shape != shape or found_dtype != dtype:
            raise ValueError(
                f"{key} is {found_dtype} {found_shape}, expected {dtype} {shape} (another aec_filter_ms?)"
            )
        count = int(np.prod(shape, dtype=np.int64))
        data = member.read(count * dtype.itemsize)
    if len(data) != count * dtype.itemsize:
        raise ValueError(f"{key} is cut short")
    array: np.ndarray = np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C").copy()
    return array


def save(file: Path, sample_rate: int, learned: LearnedEcho) -> None:
    """Write what was learned to `file` (its directory private), replacing it whole: a crash
    while writing leaves the old file, never half of one."""
    directory = ensure_private_dir(file.parent)
    fd, temporary = tempfile.mkstemp(dir=directory, prefix=f".{file.stem}.", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as out:
            np.savez(
                out,
                format=np.int64(FORMAT),
                sample_rate=np.int64(sample_rate),
                coefficients=learned.coefficients.astype(np.complex128),
                variances=learned.variances.astype(np.float64),
                echo_left_db=np.float64(learned.echo_left_db),
                residual_db=learned.residual_db.astype(np.float64),
                coupling_db=learned.coupling_db.astype(np.float64),
            )
        os.replace(temporary, file)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


@dataclass(frozen=True)
class Outcome:
    """What a restore or keep did, for the node's log."""

    ok: bool
    message: str


def restore(echo: EchoController, file: Path) -> Outcome:
    """Start `echo`'s canceller from the path kept in `file`, if there is a usable one."""
    shape = echo.echo_path_shape
    if shape is None:
        return Outcome(True, "no linear canceller: no echo path to remember")
    try:
        learned = load(file, echo.sample_rate, shape)
    except FileNotFoundError:
        return Outcome(True, f"no echo path remembered in {file} yet: learning it from the first reply")
    except (OSError, ValueError) as error:
        return Outcome(False, f"the echo path remembered in {file} is not used: {error}")
    echo.start_from_learned(learned)
    return Outcome(True, f"starting from the echo path remembered in {file}")


def keep(echo: EchoController, file: Path) -> Outcome | None:
    """Write what `echo`'s canceller learned to `file`, if it is worth remembering yet; None
    when there was nothing to write."""
    learned = echo.learned_echo()
    if learned is None:
        return None
    try:
        save(file, echo.sample_rate, learned)
    except OSError as error:
        return Outcome(False, f"could not remember the echo path in {file}: {error}")
    return Outcome(True, f"echo path remembered in {file}")
