"""WAV files become a paced stream of 16 kHz mono chunks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from by_your_command.audio.file_source import ChunkSchedule, Clip, FileSourceConfig, load_clip
from by_your_command.audio.pcm import write_wav


@pytest.mark.unit
def test_any_rate_and_channel_count_is_converted_to_16k_mono(tmp_path: Path) -> None:
    t = np.arange(44100) / 44100
    tone = (np.sin(2 * np.pi * 440 * t) * 10000).astype(np.int16)
    stereo = np.repeat(tone, 2)
    write_wav(tmp_path / "tone.wav", stereo, 44100, channels=2)
    clip = load_clip(tmp_path / "tone.wav", 16000)
    assert len(clip) == 16000
    assert 9000 < np.abs(clip).max() <= 10100


@pytest.mark.unit
def test_bad_files_fail_with_the_file_name(tmp_path: Path) -> None:
    bad = tmp_path / "not_audio.wav"
    bad.write_bytes(b"hello")
    with pytest.raises(ValueError, match="not_audio.wav: not a readable"):
        load_clip(bad, 16000)
    with pytest.raises(FileNotFoundError):
        load_clip(tmp_path / "missing.wav", 16000)


def clips() -> list[Clip]:
    return [Clip("a", np.arange(1000, dtype=np.int16)), Clip("b", np.arange(600, dtype=np.int16))]


@pytest.mark.unit
def test_schedule_paces_chunks_and_catches_up() -> None:
    config = FileSourceConfig(chunk_samples=512, rate_factor=2.0)
    schedule = ChunkSchedule(clips(), config)
    first = schedule.due(0.0)
    assert [len(c.samples) for c in first] == [512]  # the first chunk is due at once
    assert schedule.due(0.01) == []  # the next is due at 512 / 32000 s = 16 ms
    assert schedule.next_due_s() == 512 / 32000  # what the pacing thread sleeps until
    rest = schedule.due(10.0)  # after a stall everything due comes out in order
    assert [(c.stream_id, len(c.samples)) for c in rest] == [("a", 488), ("b", 512), ("b", 88)]
    assert [c.offset_s for c in first + rest] == [0.0, 512 / 16000, 1000 / 16000, 1512 / 16000]
    assert schedule.finished and schedule.samples_sent == 1600
    joined = np.concatenate([c.samples for c in first + rest])
    assert np.array_equal(joined, np.concatenate([c.samples for c in clips()]))


@pytest.mark.unit
def test_loop_restarts_and_empty_clips_are_skipped() -> None:
    config = FileSourceConfig(chunk_samples=1000, loop=True)
    schedule = ChunkSchedule([Clip("empty", np.zeros(0, dtype=np.int16)), *clips()], config)
    names = [c.stream_id for c in schedule.due(1.0, max_chunks=7)]
    assert names == ["a", "b", "a", "b", "a", "b", "a"]
    assert not schedule.finished and schedule.passes == 3
    with pytest.raises(ValueError, match="empty"):
        ChunkSchedule([], config)
    with pytest.raises(ValueError, match="empty"):
        ChunkSchedule([Clip("empty", np.zeros(0, dtype=np.int16))], config)


@pytest.mark.unit
@pytest.mark.parametrize("kwargs", [{"chunk_samples": 0}, {"rate_factor": 0.0}, {"sample_rate": -1}])
def test_bad_settings_are_refused(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        FileSourceConfig(**kwargs)  # type: ignore[arg-type]
