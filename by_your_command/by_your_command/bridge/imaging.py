"""Camera frames → JPEG for agents, treating every frame as hostile input.

Raw pixels are checked (encoding, geometry, data length, size) before anything is copied.
Compressed frames must be JPEG or PNG; their declared size is bounded from the header, before a
single pixel is decoded (Pillow's own MAX_IMAGE_PIXELS is a process-wide warning, not a limit we
choose), and a JPEG that has to shrink is reduced while it is decoded (`draft`). Every failure is
an ImageError with a kind, so callers can count them.
"""

from __future__ import annotations

import enum
import io
import warnings
from dataclasses import dataclass

import numpy as np
from PIL import Image

# ROS image encodings we accept: (channels, numpy dtype)
_RAW_ENCODINGS = {
    "rgb8": (3, np.uint8),
    "bgr8": (3, np.uint8),
    "rgba8": (4, np.uint8),
    "bgra8": (4, np.uint8),
    "mono8": (1, np.uint8),
    "mono16": (1, np.uint16),
    "8UC1": (1, np.uint8),
    "8UC3": (3, np.uint8),
    "16UC1": (1, np.uint16),
}
# What camera drivers and image_transport's compressed plugin send; nothing else is opened
# (Pillow can open dozens of formats, some through external programs).
COMPRESSED_FORMATS = ("JPEG", "PNG")
# Pillow keeps every multi-band mode in 4 bytes per pixel; 16/32-bit single-band modes in 2 or 4.
_DECODED_BYTES_PER_PIXEL = 4


class ImageErrorKind(enum.Enum):
    ENCODING = "encoding"  # a raw encoding we do not convert
    GEOMETRY = "geometry"  # width, height, step and data length disagree
    TOO_LARGE = "too_large"  # more pixels or bytes than the limits allow
    UNDECODABLE = "undecodable"  # not a JPEG/PNG, corrupt or truncated


class ImageError(ValueError):
    def __init__(self, kind: ImageErrorKind, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class ImageLimits:
    """Bounds on one input frame (the node takes them from FrameForwarderParams)."""

    max_pixels: int
    max_bytes: int  # raw data length, compressed data length, and decoded size alike


@dataclass(frozen=True)
class RawImage:
    width: int
    height: int
    encoding: str
    step: int
    data: bytes | memoryview
    is_bigendian: bool = False


@dataclass(frozen=True)
class CompressedInfo:
    format: str  # "jpeg" or "png"
    width: int
    height: int


def _too_large(what: str, value: int, limit: int) -> ImageError:
    return ImageError(ImageErrorKind.TOO_LARGE, f"{what} {value} exceeds the limit of {limit}")


def _check_size(width: int, height: int, limits: ImageLimits) -> None:
    if width <= 0 or height <= 0:
        raise ImageError(ImageErrorKind.GEOMETRY, f"bad size {width}x{height}")
    if width * height > limits.max_pixels:
        raise _too_large(f"{width}x{height} pixels =", width * height, limits.max_pixels)


def check_data_length(length: int, limits: ImageLimits) -> None:
    """Raise ImageError when a frame's data is longer than the limit (check before copying it)."""
    if length > limits.max_bytes:
        raise _too_large("frame data of", length, limits.max_bytes)


def check_raw(image: RawImage, limits: ImageLimits) -> None:
    """Raise ImageError unless the raw frame is one we can convert within the limits (no copy)."""
    spec = _RAW_ENCODINGS.get(image.encoding)
    if spec is None:
        raise ImageError(
            ImageErrorKind.ENCODING,
            f"unsupported image encoding {image.encoding[:40]!r} (supported: {sorted(_RAW_ENCODINGS)})",
        )
    channels, dtype = spec
    _check_size(image.width, image.height, limits)
    check_data_length(len(image.data), limits)
    row_bytes = image.width * channels * np.dtype(dtype).itemsize
    if image.step < row_bytes:
        raise ImageError(
            ImageErrorKind.GEOMETRY,
            f"step {image.step} is shorter than a row ({image.width} x {image.encoding} = {row_bytes} bytes)",
        )
    expected = image.step * image.height
    if len(image.data) != expected:
        raise ImageError(
            ImageErrorKind.GEOMETRY,
            f"image data has {len(image.data)} bytes, expected step x height = {expected}",
        )


def _to_pil(image: RawImage) -> Image.Image:
    channels, dtype = _RAW_ENCODINGS[image.encoding]
    row_bytes = image.width * channels * np.dtype(dtype).itemsize
    rows = np.frombuffer(image.data, dtype=np.uint8).reshape(image.height, image.step)
    element = np.dtype(dtype).newbyteorder(">" if image.is_bigendian else "<")
    pixels = rows[:, :row_bytes].copy().view(element)
    pixels = pixels.reshape(image.height, image.width, channels)
    if dtype == np.uint16:
        pixels = (pixels >> 8).astype(np.uint8)
    if image.encoding.startswith("bgr"):
        pixels = pixels[:, :, [2, 1, 0, 3][:channels]]
    if channels == 1:
        return Image.fromarray(pixels[:, :, 0], "L")
    return Image.fromarray(np.ascontiguousarray(pixels[:, :, :3]), "RGB")


def _scaled_height(width: int, height: int, max_width: int) -> int:
    return max(1, round(height * max_width / width))


def _shrink(image: Image.Image, max_width: int) -> Image.Image:
    if image.width <= max_width:
        return image
    size = (max_width, _scaled_height(image.width, image.height, max_width))
    return image.resize(size, Image.Resampling.BILINEAR, reducing_gap=2.0)


def _jpeg(image: Image.Image, quality: int) -> bytes:
    out = io.BytesIO()
    image.save(out, format="JPEG", quality=quality)
    return out.getvalue()


def encode_raw(image: RawImage, max_width: int, quality: int, limits: ImageLimits) -> bytes:
    """Raw pixels → JPEG no wider than max_width; ImageError when the frame is not acceptable."""
    check_raw(image, limits)
    return _jpeg(_shrink(_to_pil(image), max_width), quality)


def _open(data: bytes, limits: ImageLimits) -> Image.Image:
    """Open (header only) a JPEG/PNG whose declared size is within the limits."""
    check_data_length(len(data), limits)
    try:
        with warnings.catch_warnings():
            # Pillow warns (or raises) at its own global limit while opening; either way it is ours
            # to refuse, with our limit in the message.
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            image = Image.open(io.BytesIO(data), formats=COMPRESSED_FORMATS)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as error:
        raise ImageError(ImageErrorKind.TOO_LARGE, f"declared size too large: {error}") from None
    except Exception as error:  # Pillow raises many types on garbage (OSError, SyntaxError, ...)
        raise ImageError(
            ImageErrorKind.UNDECODABLE, f"not a JPEG or PNG image: {type(error).__name__}: {error}"
        ) from None
    try:
        _check_size(image.width, image.height, limits)
        decoded = image.width * image.height * _DECODED_BYTES_PER_PIXEL
        if decoded > limits.max_bytes:
            raise _too_large(f"decoded {image.width}x{image.height} image of", decoded, limits.max_bytes)
    except ImageError:
        image.close()
        raise
    return image


def probe_compressed(data: bytes, limits: ImageLimits) -> CompressedInfo:
    """Format and declared size from the header; ImageError unless JPEG/PNG within the limits."""
    with _open(data, limits) as image:
        return CompressedInfo(str(image.format).lower(), image.width, image.height)


def fit_compressed(data: bytes, max_width: int, quality: int, limits: ImageLimits) -> tuple[str, bytes]:
    """(format, bytes): passed through untouched when narrow enough, else decoded, shrunk, JPEG.

    Either way the image is decoded once within the limits, so a corrupt or truncated frame is an
    ImageError here and never reaches an agent.
    """
    with _open(data, limits) as image:
        image_format = str(image.format).lower()
        try:
            if image.width <= max_width:
                image.load()
                return image_format, data
            # JPEG decodes at 1/2, 1/4 or 1/8 scale when that is still at least the target size.
            image.draft("RGB", (max_width, _scaled_height(image.width, image.height, max_width)))
            return "jpeg", _jpeg(_shrink(image.convert("RGB"), max_width), quality)
        except Exception as error:  # truncated or corrupt data, unsupported mode
            raise ImageError(
                ImageErrorKind.UNDECODABLE,
                f"cannot decode {image_format} image: {type(error).__name__}: {error}",
            ) from None
