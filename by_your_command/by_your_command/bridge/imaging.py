"""Camera frames → JPEG for agents: raw pixels encoded, compressed frames passed through or shrunk."""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np
from PIL import Image

# ROS image encodings we accept: (channels, numpy dtype, PIL mode after conversion, channel order)
_RAW_ENCODINGS = {
    "rgb8": (3, np.uint8),
    "bgr8": (3, np.uint8),
    "rgba8": (4, np.uint8),
    "bgra8": (4, np.uint8),
    "mono8": (1, np.uint8),
    "mono16": (1, np.uint16),
    "8UC1": (1, np.uint8),
    "8UC3": (3, np.uint8),
}


class ImageError(ValueError):
    pass


@dataclass(frozen=True)
class RawImage:
    width: int
    height: int
    encoding: str
    step: int
    data: bytes | memoryview
    is_bigendian: bool = False


def _to_pil(image: RawImage) -> Image.Image:
    spec = _RAW_ENCODINGS.get(image.encoding)
    if spec is None:
        raise ImageError(
            f"unsupported image encoding {image.encoding!r} (supported: {sorted(_RAW_ENCODINGS)})"
        )
    channels, dtype = spec
    itemsize = np.dtype(dtype).itemsize
    row_bytes = image.width * channels * itemsize
    if image.width <= 0 or image.height <= 0 or image.step < row_bytes:
        raise ImageError(f"bad geometry {image.width}x{image.height} step {image.step} for {image.encoding}")
    if len(image.data) < image.step * image.height:
        raise ImageError(f"image data has {len(image.data)} bytes, expected {image.step * image.height}")
    rows = np.frombuffer(image.data, dtype=np.uint8, count=image.step * image.height).reshape(
        image.height, -1
    )
    pixels = rows[:, :row_bytes].copy().view(np.dtype(dtype).newbyteorder(">" if image.is_bigendian else "<"))
    pixels = pixels.reshape(image.height, image.width, channels)
    if dtype == np.uint16:
        pixels = (pixels >> 8).astype(np.uint8)
    if image.encoding.startswith("bgr"):
        pixels = pixels[:, :, [2, 1, 0, 3][:channels]]
    if channels == 1:
        return Image.fromarray(pixels[:, :, 0], "L")
    return Image.fromarray(np.ascontiguousarray(pixels[:, :, :3]), "RGB")


def _shrink(image: Image.Image, max_width: int) -> Image.Image:
    if image.width <= max_width:
        return image
    height = max(1, round(image.height * max_width / image.width))
    return image.resize((max_width, height), Image.Resampling.BILINEAR)


def _jpeg(image: Image.Image, quality: int) -> bytes:
    out = io.BytesIO()
    image.save(out, format="JPEG", quality=quality)
    return out.getvalue()


def encode_raw(image: RawImage, max_width: int, quality: int) -> bytes:
    """Raw pixels → JPEG no wider than max_width."""
    return _jpeg(_shrink(_to_pil(image), max_width), quality)


def fit_compressed(data: bytes, max_width: int, quality: int) -> tuple[str, bytes]:
    """(format, bytes): passed through untouched when narrow enough, else decoded, shrunk, JPEG."""
    try:
        with Image.open(io.BytesIO(data)) as image:  # reads the header only until pixels are needed
            if image.width <= max_width:
                return (image.format or "jpeg").lower(), data
            return "jpeg", _jpeg(_shrink(image.convert("RGB"), max_width), quality)
    except (OSError, ValueError) as error:  # PIL raises UnidentifiedImageError (an OSError) on garbage
        raise ImageError(f"cannot decode compressed image: {error}") from None
