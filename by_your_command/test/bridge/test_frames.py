"""Frame forwarding policy and image encoding (pure)."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from by_your_command.bridge.frames import FrameForwarder, FrameForwarderParams
from by_your_command.bridge.imaging import ImageError, RawImage, encode_raw, fit_compressed

pytestmark = pytest.mark.unit


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def forwarder(**overrides: object) -> tuple[FrameForwarder[str], Clock]:
    clock = Clock()
    return FrameForwarder(FrameForwarderParams(**overrides), clock), clock  # type: ignore[arg-type]


def test_baseline_rate_limits_forwarding() -> None:
    ff, clock = forwarder(max_video_fps=0.5)
    sent = []
    for index in range(60):  # 10 fps camera for 6 s
        clock.now = 100.0 + index / 10
        result = ff.on_frame(f"f{index}")
        if result:
            sent.append(result.frame)
    assert sent == ["f0", "f20", "f40"]


def test_voice_start_forwards_the_latest_fresh_frame_at_once() -> None:
    ff, clock = forwarder(max_video_fps=0)
    assert ff.on_frame("f1") is None and ff.on_frame("f2") is None
    clock.now += 0.2
    result = ff.on_voice_activity(True)
    assert result is not None and result.frame == "f2" and result.reason == "voice"
    assert result.age_ms == pytest.approx(200)
    assert ff.on_voice_activity(False) is None
    assert ff.on_text() is None  # same frame again: the agent already has it
    assert ff.on_frame("f3") is not None  # ... so the next frame is sent as soon as it comes
    assert ff.stats.forwarded == {"voice": 1, "text/late": 1}


def test_stale_frames_are_never_forwarded_and_triggers_wait_for_a_fresh_one() -> None:
    ff, clock = forwarder(max_video_fps=0, max_frame_age_ms=1000, trigger_wait_ms=300)
    ff.on_frame("old")
    clock.now += 1.5
    assert ff.on_text() is None
    clock.now += 0.1
    late = ff.on_frame("new")
    assert late is not None and late.frame == "new" and late.reason == "text/late"
    assert ff.on_text() is None
    clock.now += 0.5  # the waiting trigger expires
    assert ff.on_frame("newer") is None
    assert ff.stats.stale_triggers == 1


def test_every_nth_voice_chunk_and_disabled_triggers() -> None:
    ff, clock = forwarder(max_video_fps=0, nth_voice_chunk=3, trigger_wait_ms=0)
    reasons = []
    for sequence in range(7):
        clock.now += 0.05
        ff.on_frame(f"f{sequence}")
        result = ff.on_voice_chunk(sequence)
        reasons.append(result.frame if result else None)
    assert reasons == ["f0", None, None, "f3", None, None, "f6"]
    quiet, _ = forwarder(max_video_fps=0, trigger_on_voice=False, trigger_on_text=False, nth_voice_chunk=0)
    quiet.on_frame("f")
    assert (
        quiet.on_voice_activity(True) is None and quiet.on_text() is None and quiet.on_voice_chunk(0) is None
    )


def test_bad_params_are_refused() -> None:
    with pytest.raises(ValueError, match="image_transport"):
        FrameForwarderParams(image_transport="theora")
    with pytest.raises(ValueError):
        FrameForwarderParams(jpeg_quality=0)


def _decode(data: bytes) -> Image.Image:
    return Image.open(io.BytesIO(data))


def test_raw_bgr_is_encoded_resized_and_in_rgb_order() -> None:
    height, width = 60, 200
    pixels = np.zeros((height, width, 3), np.uint8)
    pixels[:, :, 0] = 255  # blue in BGR
    padded_step = width * 3 + 8
    data = np.zeros((height, padded_step), np.uint8)
    data[:, : width * 3] = pixels.reshape(height, -1)
    jpeg = encode_raw(RawImage(width, height, "bgr8", padded_step, data.tobytes()), max_width=100, quality=80)
    image = _decode(jpeg)
    assert image.format == "JPEG" and image.size == (100, 30)
    red, green, blue = image.convert("RGB").getpixel((50, 15))  # type: ignore[misc]
    assert blue > 200 and red < 50 and green < 50


def test_mono16_and_bad_raw_images() -> None:
    data = (np.arange(64 * 32, dtype=np.uint16) * 16).tobytes()
    assert _decode(encode_raw(RawImage(64, 32, "mono16", 128, data), 640, 80)).size == (64, 32)
    with pytest.raises(ImageError, match="unsupported image encoding"):
        encode_raw(RawImage(4, 4, "yuv422", 8, bytes(32)), 640, 80)
    with pytest.raises(ImageError, match="expected"):
        encode_raw(RawImage(4, 4, "rgb8", 12, bytes(10)), 640, 80)


def test_compressed_frames_pass_through_unless_too_wide() -> None:
    out = io.BytesIO()
    Image.new("RGB", (320, 240), "green").save(out, format="JPEG")
    small = out.getvalue()
    assert fit_compressed(small, 640, 80) == ("jpeg", small)
    image_format, shrunk = fit_compressed(small, 160, 80)
    assert image_format == "jpeg" and _decode(shrunk).size == (160, 120)
    with pytest.raises(ImageError):
        fit_compressed(b"not an image", 640, 80)
