"""The linear canceller's echo path, kept in a file across restarts.

A new canceller needs seconds of the robot's voice before it cancels well (1-5 dB in the first
2 s of a reverberant room): a user who talks over the first reply after a start was taken down
by the residual suppressor and heard late. The speaker-to-mic path of a robot changes little
between runs, so the node keeps what it learned (at the end of each reply and at shutdown) and
starts from it. The file is input like any other: a file that is not one of ours, of another
rate or filter length, or with absurd values is refused with the reason, and the canceller
starts new. One that loads but belongs to another room is dropped by the canceller itself
(audio/echo_linear.py: the remembered path is on trial for its first seconds).
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from by_your_command.audio.echo import EchoController
from by_your_command.audio.echo_linear import ComplexArray
from by_your_command.audio.recording import ensure_private_dir

FORMAT = 1
KEYS = frozenset({"format", "sample_rate", "coefficients"})
MAX_FILE_BYTES = 16 * 1024 * 1024  # the longest filter (2 s at 48 kHz) takes 1.5 MB
# |coefficient| is a partition's gain at one frequency: 100 is an echo 40 dB over what played.
MAX_COEFFICIENT = 100.0


def default_file(node_name: str) -> Path:
    """$XDG_STATE_HOME/by_your_command/echo_path/<node's full name>.npz (~/.local/state/... when
    unset): one file per node, so two robots' nodes on one machine keep their own."""
    state = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    name = node_name.strip("/").replace("/", ".") or "echo"
    return Path(state) / "by_your_command" / "echo_path" / f"{name}.npz"


def memory_file(setting: str, node_name: str) -> Path | None:
    """The file for an `aec_echo_memory` setting: auto, none or a path."""
    if setting == "none":
        return None
    if setting == "auto":
        return default_file(node_name)
    return Path(setting).expanduser()


def load(file: Path, sample_rate: int, shape: tuple[int, int]) -> ComplexArray:
    """The echo path kept in `file` for a canceller at `sample_rate` of `shape`. Raises
    FileNotFoundError if there is none, ValueError (with the reason) if it is not usable."""
    size = file.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ValueError(f"{size} bytes, more than an echo path takes ({MAX_FILE_BYTES})")
    try:
        with zipfile.ZipFile(file) as archive:
            names = {info.filename for info in archive.infolist()}
            if names != {f"{key}.npy" for key in KEYS}:
                raise ValueError(f"holds {sorted(names)}, an echo path file holds {sorted(KEYS)}")
            version = _read(archive, "format", (), np.dtype(np.int64))
            rate = _read(archive, "sample_rate", (), np.dtype(np.int64))
            if int(version) != FORMAT:
                raise ValueError(f"format {int(version)}, this version reads format {FORMAT}")
            if int(rate) != sample_rate:
                raise ValueError(f"learned at {int(rate)} Hz, the canceller runs at {sample_rate} Hz")
            coefficients = _read(archive, "coefficients", shape, np.dtype(np.complex128))
    except (zipfile.BadZipFile, EOFError) as error:
        raise ValueError(f"not an echo path file ({error})") from None
    if not np.all(np.isfinite(coefficients)):
        raise ValueError("values that are not finite")
    if float(np.max(np.abs(coefficients), initial=0.0)) > MAX_COEFFICIENT:
        raise ValueError(f"a gain over {MAX_COEFFICIENT:g}: not an echo path")
    path: ComplexArray = coefficients
    return path


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


def save(file: Path, sample_rate: int, coefficients: ComplexArray) -> None:
    """Write the echo path to `file` (its directory private), replacing it whole: a crash while
    writing leaves the old file, never half of one."""
    directory = ensure_private_dir(file.parent)
    fd, temporary = tempfile.mkstemp(dir=directory, prefix=f".{file.stem}.", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as out:
            np.savez(
                out,
                format=np.int64(FORMAT),
                sample_rate=np.int64(sample_rate),
                coefficients=coefficients.astype(np.complex128),
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
        path = load(file, echo.sample_rate, shape)
    except FileNotFoundError:
        return Outcome(True, f"no echo path remembered in {file} yet: learning it from the first reply")
    except (OSError, ValueError) as error:
        return Outcome(False, f"the echo path remembered in {file} is not used: {error}")
    echo.start_from_echo_path(path)
    return Outcome(True, f"starting from the echo path remembered in {file}")


def keep(echo: EchoController, file: Path) -> Outcome | None:
    """Write what `echo`'s canceller learned to `file`, if it is worth remembering yet; None
    when there was nothing to write."""
    path = echo.echo_path()
    if path is None:
        return None
    try:
        save(file, echo.sample_rate, path)
    except OSError as error:
        return Outcome(False, f"could not remember the echo path in {file}: {error}")
    return Outcome(True, f"echo path remembered in {file}")
