"""Device listing/selection on a fake PortAudio device list, dead-input detection, capture queue."""

from __future__ import annotations

import sys
import time
import types

import numpy as np
import pytest

from by_your_command.audio.devices import (
    CaptureConfig,
    CapturedChunk,
    CaptureMonitor,
    CaptureQueue,
    CaptureStream,
    DeadInputDetector,
    DeviceNotFoundError,
    format_devices,
    parse_devices,
    select_device,
)

# The shape sounddevice.query_devices() returns (a DeviceList of dicts).
FAKE = [
    {"name": "HDA Intel PCH: ALC3246 Analog (hw:0,0)", "index": 0, "hostapi": 0,
     "max_input_channels": 2, "max_output_channels": 2, "default_samplerate": 44100.0},
    {"name": "HDMI 0 (hw:0,3)", "index": 1, "hostapi": 0,
     "max_input_channels": 0, "max_output_channels": 8, "default_samplerate": 48000.0},
    {"name": "EMEET OfficeCore M0 Plus: USB Audio (hw:2,0)", "index": 2, "hostapi": 0,
     "max_input_channels": 1, "max_output_channels": 2, "default_samplerate": 16000.0},
    {"name": "pulse", "index": 3, "hostapi": 0,
     "max_input_channels": 32, "max_output_channels": 32, "default_samplerate": 44100.0},
]  # fmt: skip


@pytest.mark.unit
def test_select_by_name_substring_is_case_insensitive_and_direction_aware() -> None:
    devices = parse_devices(FAKE)
    assert select_device(devices, "emeet", "input").index == 2
    assert select_device(devices, "HDMI", "output").index == 1
    with pytest.raises(DeviceNotFoundError, match="HDMI"):
        select_device(devices, "HDMI", "input")  # HDMI has no input channels


@pytest.mark.unit
def test_select_by_index_and_default() -> None:
    devices = parse_devices(FAKE)
    assert select_device(devices, "3", "input").name == "pulse"
    assert select_device(devices, "", "input", default=2).index == 2
    assert select_device(devices, "", "output", default=-1).index == 0  # no default: first usable
    with pytest.raises(DeviceNotFoundError, match="index 1"):
        select_device(devices, "1", "input")


@pytest.mark.unit
def test_no_device_error_names_what_was_looked_for_and_what_exists() -> None:
    with pytest.raises(DeviceNotFoundError) as error:
        select_device(parse_devices(FAKE), "Blue Yeti", "input")
    message = str(error.value)
    assert "'Blue Yeti'" in message and "2: EMEET" in message and "--list-devices" in message
    with pytest.raises(DeviceNotFoundError, match="default input device.*none"):
        select_device([], "", "input")


@pytest.mark.unit
def test_listing_marks_defaults_and_says_when_empty() -> None:
    table = format_devices(parse_devices(FAKE), default_input=2, default_output=1)
    lines = table.splitlines()
    assert any(line.startswith(">") and "EMEET" in line for line in lines)
    assert any(line.startswith("<") and "HDMI" in line for line in lines)
    assert "no audio devices" in format_devices([])


@pytest.mark.unit
def test_dead_input_is_reported_once_and_recovery_once() -> None:
    detector = DeadInputDetector(sample_rate=16000, seconds=1.0)
    zeros = np.zeros(512, dtype=np.int16)
    events = [detector.update(zeros) for _ in range(40)]  # 1.28 s of exact zeros
    assert events.count("dead") == 1 and events.index("dead") == 31  # 32 blocks = 1.024 s
    assert detector.update(np.full(512, 1, dtype=np.int16)) == "alive"
    assert detector.update(zeros) is None


@pytest.mark.unit
def test_quiet_but_live_input_is_not_dead() -> None:
    detector = DeadInputDetector(sample_rate=16000, seconds=0.5)
    rng = np.random.default_rng(0)
    quiet = [rng.integers(-1, 2, 512).astype(np.int16) for _ in range(100)]  # ±1 LSB hiss
    assert all(detector.update(block) is None for block in quiet)


@pytest.mark.unit
def test_capture_queue_counts_overruns_instead_of_blocking() -> None:
    captured = CaptureQueue(max_chunks=2)
    indata = np.ones((512, 1), dtype=np.int16)
    for k in range(5):
        captured.push(indata, k, overflowed=(k == 4))
    assert captured.overruns == 3 and captured.device_overflows == 1
    assert captured.first_callback.is_set()
    first = captured.get(timeout=0.1)
    assert first is not None and first.start_ns == 0 and first.pcm.shape == (512,)
    indata[:] = 7  # the callback's buffer is reused by PortAudio: the queue must hold a copy
    assert first.pcm[0] == 1


@pytest.mark.unit
def test_capture_config_rejects_nonsense() -> None:
    with pytest.raises(ValueError):
        CaptureConfig(chunk=0)
    with pytest.raises(ValueError):
        CaptureConfig(dead_input_s=0)


class FakeInputStream:
    """Stands in for sounddevice.InputStream: remembers the callback so the test can 'capture'."""

    last: FakeInputStream | None = None

    def __init__(self, **kwargs: object) -> None:
        self.kwargs = kwargs
        self.channels = int(kwargs["channels"])  # type: ignore[call-overload]
        self.started = self.closed = False
        FakeInputStream.last = self

    def start(self) -> None:
        self.started = True

    def abort(self) -> None:
        self.started = False

    def close(self) -> None:
        self.closed = True


class FakeTime:
    def __init__(self, current: float, adc: float) -> None:
        self.currentTime, self.inputBufferAdcTime = current, adc


class FakeStatus:
    def __init__(self, overflow: bool) -> None:
        self.input_overflow = overflow


@pytest.fixture
def fake_sounddevice(monkeypatch: pytest.MonkeyPatch) -> types.SimpleNamespace:
    fake = types.SimpleNamespace(InputStream=FakeInputStream, PortAudioError=RuntimeError)
    monkeypatch.setitem(sys.modules, "sounddevice", fake)
    return fake


@pytest.mark.unit
def test_capture_stream_stamps_chunks_with_the_first_sample_time(fake_sounddevice: object) -> None:
    config = CaptureConfig(device="EMEET", chunk=512, channels=2)
    device = select_device(parse_devices(FAKE), config.device)
    captured = CaptureQueue(8)
    stream = CaptureStream(config, device, captured)
    fake = FakeInputStream.last
    assert fake is not None and fake.started
    assert fake.kwargs["device"] == 2 and fake.kwargs["blocksize"] == 512 and fake.kwargs["dtype"] == "int16"
    assert stream.channels == 1  # the EMEET has one input channel: asked for 2, opened 1
    callback = fake.kwargs["callback"]
    before = time.time_ns()
    callback(np.ones((512, 1), dtype=np.int16), 512, FakeTime(10.050, 10.000), FakeStatus(False))
    chunk = captured.get(timeout=1)
    assert chunk is not None
    assert before - 60_000_000 <= chunk.start_ns <= time.time_ns() - 50_000_000  # 50 ms in the past
    stream.close()
    assert fake.closed


@pytest.mark.unit
def test_capture_monitor_says_ready_once_then_dead_input_then_losses() -> None:
    config = CaptureConfig(sample_rate=16000, chunk=512, dead_input_s=0.1)
    captured = CaptureQueue(2)
    monitor = CaptureMonitor(config, channels=2, captured=captured)
    stereo = CapturedChunk(np.zeros(1024, dtype=np.int16), 0)
    mono, events = monitor.process(stereo)
    assert len(mono) == 512 and [e.text for e in events] == ["ready: audio is flowing"]
    texts = [e.text for _ in range(5) for e in monitor.process(stereo)[1]]
    assert len(texts) == 1 and "digital silence" in texts[0]
    captured.overruns = 3
    _, events = monitor.process(CapturedChunk(np.ones(1024, dtype=np.int16), 0))
    assert [e.level for e in events] == ["info", "warning"] and "3 audio chunks lost" in events[1].text
