"""The recorder writes one WAV per utterance (or per stream) at the rate the messages carry."""

from __future__ import annotations

import os
import stat
import wave
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from by_your_command.audio.pcm import read_wav
from by_your_command.audio.recording import (
    RecorderConfig,
    StreamRecorder,
    UtteranceRecorder,
    default_recordings_dir,
    ensure_private_dir,
)


def fixed_now() -> datetime:
    return datetime(2026, 11, 21, 10, 30, 5)


def pcm(n: int, value: int = 100) -> np.ndarray:
    return np.full(n, value, dtype=np.int16)


@pytest.mark.unit
def test_one_file_per_utterance_closed_by_the_end_marker(tmp_path: Path) -> None:
    recorder = UtteranceRecorder(tmp_path / "rec", 2.0, fixed_now)
    assert recorder.add(111, pcm(512), 16000, False, 0.0) == []
    (path,) = recorder.add(111, pcm(100, 7), 16000, True, 0.1)
    assert path.name == "utterance_111_20261121_103005.wav"
    samples, rate, channels = read_wav(path)
    assert (len(samples), rate, channels) == (612, 16000, 1)
    assert samples[-1] == 7
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "rec").stat().st_mode) == 0o700


@pytest.mark.unit
def test_new_id_or_timeout_closes_the_open_file(tmp_path: Path) -> None:
    recorder = UtteranceRecorder(tmp_path, 2.0, fixed_now)
    recorder.add(1, pcm(10), 16000, False, 0.0)
    (first,) = recorder.add(2, pcm(20), 24000, False, 0.5)  # a new utterance id closes the first
    assert first.name.startswith("utterance_1_")
    assert recorder.poll(2.0) == []
    (second,) = recorder.poll(2.6)
    with wave.open(str(second)) as wav:
        assert (wav.getframerate(), wav.getnframes()) == (24000, 20)
    # the same id again (a late chunk) gets a distinct file name
    recorder.add(1, pcm(10), 16000, True, 3.0)
    assert len(list(tmp_path.glob("utterance_1_*.wav"))) == 2


@pytest.mark.unit
def test_stream_mode_keeps_rate_and_splits_on_stream_change(tmp_path: Path) -> None:
    recorder = StreamRecorder(tmp_path, 1.0, fixed_now)
    assert recorder.add("resp-1", pcm(2400), 24000, 1, 0.0) == []
    recorder.add("resp-1", pcm(2400), 24000, 1, 0.1)
    (first,) = recorder.add("../evil/name", pcm(160), 16000, 1, 0.2)
    assert first.name == "response_resp-1_20261121_103005.wav"
    samples, rate, _ = read_wav(first)
    assert (len(samples), rate) == (4800, 24000)
    (second,) = recorder.close()
    assert second.parent == tmp_path  # stream ids cannot steer the file elsewhere
    assert second.name == "response____evil_name_20261121_103005.wav"
    with pytest.raises(ValueError):
        recorder.add("x", pcm(1), 0, 1, 1.0)


@pytest.mark.unit
def test_world_writable_directories_are_refused(tmp_path: Path) -> None:
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)
    with pytest.raises(PermissionError, match="world-writable"):
        ensure_private_dir(shared)


@pytest.mark.unit
def test_default_directory_is_the_users_state_dir(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    assert default_recordings_dir() == tmp_path / "by_your_command" / "recordings"
    assert RecorderConfig().directory() == default_recordings_dir()
    monkeypatch.delenv("XDG_STATE_HOME")
    assert default_recordings_dir() == Path.home() / ".local" / "state" / "by_your_command" / "recordings"
    with pytest.raises(ValueError):
        RecorderConfig(input_mode="both")
