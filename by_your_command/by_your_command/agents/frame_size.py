"""The pixel size of a camera frame, read from its JPEG header (no pixel is decoded).

Detections come in 0–1000 coordinates of the frame the model was shown; the runtime turns them into
pixels with this size. The frame is untrusted: anything that is not a readable JPEG gives None.
"""

from __future__ import annotations

import io
import warnings

from PIL import Image, UnidentifiedImageError

MAX_SIDE = 65_535  # the largest side a JPEG can declare


def jpeg_size(jpeg: bytes) -> tuple[int, int] | None:
    """(width, height), or None for bytes that are not a JPEG with a sane size."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # only the header is read
            with Image.open(io.BytesIO(jpeg), formats=["JPEG"]) as image:
                width, height = image.size
    except (UnidentifiedImageError, Image.DecompressionBombError, OSError, ValueError, SyntaxError):
        return None
    if not (0 < width <= MAX_SIDE and 0 < height <= MAX_SIDE):
        return None
    return width, height
