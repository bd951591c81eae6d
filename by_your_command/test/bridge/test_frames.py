"""Frame forwarding policy and image encoding (pure)."""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image, ImageFile

from by_your_command.bridge.frames import ErrorTally, FrameForwarder, FrameForwarderParams
from by_your_command.bridge.imaging import (
    ImageError,
    ImageErrorKind,
    ImageLimits,
    RawImage,
    encode_raw,
    fit_compressed,
    probe_compressed,
)

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
    with pytest.raises(ValueError, match="max_input_pixels"):
        FrameForwarderParams(max_input_pixels=0)


def test_error_tally_counts_everything_and_logs_each_kind_at_most_once_per_interval() -> None:
    clock = Clock()
    tally = ErrorTally(interval_s=10.0, clock=clock)
    logged = [tally.record(kind) for kind in ("geometry", "geometry", "too_large", "geometry")]
    assert logged == [True, False, True, False]  # the first of each kind at once, then quiet
    clock.now += 10.0
    assert tally.record("geometry") is True
    assert tally.counts == {"geometry": 4, "too_large": 1} and tally.total == 5 and tally.unlogged == 2
    every = ErrorTally(interval_s=0.0, clock=clock)
    assert all(every.record("x") for _ in range(3))


def _decode(data: bytes) -> Image.Image:
    return Image.open(io.BytesIO(data))


LIMITS = ImageLimits(max_pixels=4096 * 4096, max_bytes=64 * 1024 * 1024)


def _encoded(image: Image.Image, image_format: str, **options: object) -> bytes:
    out = io.BytesIO()
    image.save(out, format=image_format, **options)
    return out.getvalue()


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def forged_png(width: int, height: int) -> bytes:
    """A valid PNG header declaring width x height RGB pixels, with a few bytes of pixel data."""
    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    pixels = zlib.compress(b"\0" * 64)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", header)
        + _png_chunk(b"IDAT", pixels)
        + _png_chunk(b"IEND", b"")
    )


def forged_jpeg(width: int, height: int) -> bytes:
    """A real 16x16 JPEG whose frame header (SOF0) is patched to declare width x height."""
    data = bytearray(_encoded(Image.new("RGB", (16, 16), "red"), "JPEG"))
    sof = data.find(b"\xff\xc0")
    data[sof + 5 : sof + 9] = struct.pack(">HH", height, width)
    return bytes(data)


@pytest.fixture
def pixel_decodes(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[tuple[int, int]]]:
    """Records the size of every image Pillow decodes (ImageFile.load), to show what was not decoded."""
    decoded: list[tuple[int, int]] = []
    original = ImageFile.ImageFile.load

    def load(self: ImageFile.ImageFile) -> object:
        decoded.append(self.size)
        return original(self)

    monkeypatch.setattr(ImageFile.ImageFile, "load", load)
    yield decoded


# Small files that declare far more pixels than the limit: forged headers (60000 x 60000 is 3.6
# gigapixels, 10.8 GB as RGB) and a real, decodable 4-megapixel PNG of zeros against a 1 Mpx limit.
BOMBS = {
    "png_60000": (forged_png(60000, 60000), LIMITS),
    "jpeg_60000": (forged_jpeg(60000, 60000), LIMITS),
    "png_just_over_pillow_warning": (forged_png(10000, 9000), LIMITS),
    "png_real_4mpx": (
        _encoded(Image.new("1", (2000, 2000)), "PNG"),
        ImageLimits(max_pixels=1_000_000, max_bytes=64 * 1024 * 1024),
    ),
}


@pytest.mark.parametrize("name", sorted(BOMBS))
def test_decompression_bombs_are_refused_from_the_header_without_decoding(
    name: str, pixel_decodes: list[tuple[int, int]]
) -> None:
    data, limits = BOMBS[name]
    assert len(data) < 2000  # a bomb: tiny on the wire
    for attempt in (
        lambda: probe_compressed(data, limits),
        lambda: fit_compressed(data, 640, 80, limits),
        lambda: fit_compressed(data, 100_000, 80, limits),  # even when it would pass through
    ):
        with pytest.raises(ImageError) as refused:
            attempt()
        assert refused.value.kind is ImageErrorKind.TOO_LARGE, refused.value
        assert "exceeds the limit" in str(refused.value) or "too large" in str(refused.value)
    assert pixel_decodes == []  # refused before a single pixel was decoded


def test_a_declared_size_within_pillows_global_limit_is_still_refused_with_ours(
    pixel_decodes: list[tuple[int, int]],
) -> None:
    data = forged_png(3000, 3000)  # 9 Mpx: no warning from Pillow at all
    with pytest.raises(ImageError, match="exceeds the limit of 1000000"):
        fit_compressed(data, 640, 80, ImageLimits(max_pixels=1_000_000, max_bytes=10**9))
    with pytest.raises(ImageError, match="decoded 3000x3000 image"):  # the byte bound, 36 MB decoded
        fit_compressed(data, 640, 80, ImageLimits(max_pixels=10**9, max_bytes=10_000_000))
    assert pixel_decodes == []


def test_a_wide_jpeg_is_reduced_while_decoding(pixel_decodes: list[tuple[int, int]]) -> None:
    gradient = np.add.outer(np.arange(1536), np.arange(2048)).astype(np.uint8)
    data = _encoded(Image.fromarray(gradient, "L").convert("RGB"), "JPEG")
    image_format, shrunk = fit_compressed(data, 256, 80, LIMITS)
    assert image_format == "jpeg" and _decode(shrunk).size == (256, 192)
    assert pixel_decodes[0] == (256, 192)  # decoded at 1/8 scale, never at 2048 x 1536


def test_corrupt_and_truncated_frames_never_pass_through() -> None:
    jpeg = _encoded(Image.new("RGB", (320, 240), "green"), "JPEG")
    png = _encoded(Image.effect_noise((64, 64), 50), "PNG")
    for data in (jpeg[: len(jpeg) // 2], png[: len(png) // 2]):
        probe_compressed(data, LIMITS)  # the header alone looks fine
        with pytest.raises(ImageError) as refused:
            fit_compressed(data, 640, 80, LIMITS)  # narrow enough to pass through: decoded anyway
        assert refused.value.kind is ImageErrorKind.UNDECODABLE
    gif = _encoded(Image.new("RGB", (8, 8)), "GIF")
    with pytest.raises(ImageError, match="not a JPEG or PNG") as refused:
        probe_compressed(gif, LIMITS)
    assert refused.value.kind is ImageErrorKind.UNDECODABLE
    with pytest.raises(ImageError, match="frame data of 65 exceeds the limit of 64"):
        probe_compressed(bytes(65), ImageLimits(max_pixels=100, max_bytes=64))


_VALID_JPEG = _encoded(Image.effect_noise((48, 32), 40).convert("RGB"), "JPEG")
_VALID_PNG = _encoded(Image.effect_noise((48, 32), 40), "PNG")


@settings(max_examples=300, deadline=None)
@given(
    st.one_of(
        st.binary(max_size=512),
        st.sampled_from([_VALID_JPEG, _VALID_PNG]).flatmap(
            lambda data: st.lists(
                st.tuples(st.integers(0, len(data) - 1), st.integers(0, 255)), max_size=8
            ).map(lambda edits, data=data: _mutated(data, edits))
        ),
    )
)
def test_random_and_mutated_bytes_give_an_image_or_an_image_error(data: bytes) -> None:
    for max_width in (640, 16):
        try:
            image_format, out = fit_compressed(data, max_width, 80, LIMITS)
        except ImageError as error:
            assert isinstance(error.kind, ImageErrorKind) and str(error)
        else:
            assert image_format in ("jpeg", "png") and _decode(out).width <= max(max_width, 48)


def _mutated(data: bytes, edits: list[tuple[int, int]]) -> bytes:
    mutable = bytearray(data)
    for index, value in edits:
        mutable[index] = value
    return bytes(mutable)


def test_raw_bgr_is_encoded_resized_and_in_rgb_order() -> None:
    height, width = 60, 200
    pixels = np.zeros((height, width, 3), np.uint8)
    pixels[:, :, 0] = 255  # blue in BGR
    padded_step = width * 3 + 8
    data = np.zeros((height, padded_step), np.uint8)
    data[:, : width * 3] = pixels.reshape(height, -1)
    raw = RawImage(width, height, "bgr8", padded_step, data.tobytes())
    jpeg = encode_raw(raw, max_width=100, quality=80, limits=LIMITS)
    image = _decode(jpeg)
    assert image.format == "JPEG" and image.size == (100, 30)
    red, green, blue = image.convert("RGB").getpixel((50, 15))  # type: ignore[misc]
    assert blue > 200 and red < 50 and green < 50


def test_mono16_raw_image() -> None:
    data = (np.arange(64 * 32, dtype=np.uint16) * 16).tobytes()
    assert _decode(encode_raw(RawImage(64, 32, "mono16", 128, data), 640, 80, LIMITS)).size == (64, 32)


BAD_RAW = {
    "unknown encoding": (RawImage(4, 4, "yuv422", 8, bytes(32)), ImageErrorKind.ENCODING),
    "data too short": (RawImage(4, 4, "rgb8", 12, bytes(10)), ImageErrorKind.GEOMETRY),
    "data too long": (RawImage(4, 4, "rgb8", 12, bytes(49)), ImageErrorKind.GEOMETRY),
    "step shorter than a row": (RawImage(4, 4, "rgb8", 11, bytes(44)), ImageErrorKind.GEOMETRY),
    "zero width": (RawImage(0, 4, "rgb8", 0, b""), ImageErrorKind.GEOMETRY),
    "absurd declared size": (RawImage(60000, 60000, "rgb8", 180000, bytes(12)), ImageErrorKind.TOO_LARGE),
    "absurd step": (RawImage(4, 4, "mono8", 2**31, bytes(16)), ImageErrorKind.GEOMETRY),
    "mono16 step too short": (RawImage(4, 2, "mono16", 4, bytes(8)), ImageErrorKind.GEOMETRY),
}


@pytest.mark.parametrize("name", sorted(BAD_RAW))
def test_inconsistent_raw_images_are_refused_with_a_kind(name: str) -> None:
    image, kind = BAD_RAW[name]
    with pytest.raises(ImageError) as refused:
        encode_raw(image, 640, 80, LIMITS)
    assert refused.value.kind is kind, refused.value


def test_raw_images_over_the_byte_limit_and_long_encodings_are_refused_briefly() -> None:
    image = RawImage(16, 16, "rgba8", 64, bytes(1024))
    assert encode_raw(image, 640, 80, LIMITS)
    with pytest.raises(ImageError, match="frame data of 1024 exceeds the limit of 1000"):
        encode_raw(image, 640, 80, ImageLimits(max_pixels=10**6, max_bytes=1000))
    with pytest.raises(ImageError, match="exceeds the limit of 255") as refused:
        encode_raw(image, 640, 80, ImageLimits(max_pixels=255, max_bytes=10**6))
    assert refused.value.kind is ImageErrorKind.TOO_LARGE
    with pytest.raises(ImageError) as refused:
        encode_raw(RawImage(4, 4, "x" * 1_000_000, 12, bytes(48)), 640, 80, LIMITS)
    assert len(str(refused.value)) < 300  # a hostile string is not echoed into the log


def test_compressed_frames_pass_through_unless_too_wide() -> None:
    out = io.BytesIO()
    Image.new("RGB", (320, 240), "green").save(out, format="JPEG")
    small = out.getvalue()
    assert fit_compressed(small, 640, 80, LIMITS) == ("jpeg", small)
    image_format, shrunk = fit_compressed(small, 160, 80, LIMITS)
    assert image_format == "jpeg" and _decode(shrunk).size == (160, 120)
    png = _encoded(Image.new("RGB", (64, 48), "blue"), "PNG")
    assert fit_compressed(png, 640, 80, LIMITS) == ("png", png)
    with pytest.raises(ImageError, match="not a JPEG or PNG"):
        fit_compressed(b"not an image", 640, 80, LIMITS)
