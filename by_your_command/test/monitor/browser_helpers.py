"""Shared by the browser tests: a Chromium page fixture, DOM queries, and test images."""

from __future__ import annotations

import base64
import io
from collections.abc import Iterator
from typing import Any

import pytest
from byc_testing import wait_for
from cdp import Browser, Page, chromium_binary, headless_chromium
from PIL import Image, ImageDraw

# What the page shows, read back as plain data (textContent only, like the page writes it).
TRANSCRIPT = (
    "Array.from(document.querySelectorAll('#transcript li'))"
    ".map(li => [li.dataset.kind, li.querySelector('.text').textContent])"
)


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    binary = chromium_binary()
    if binary is None:  # the bootstrap installs it: a missing browser is a broken setup, not a skip
        pytest.fail(
            "chromium is not installed: run scripts/bootstrap.sh (Debian packages chromium, chromium-driver)"
        )
    with headless_chromium(binary) as running:
        yield running


def transcript(page: Page) -> list[tuple[str, str]]:
    return [(kind, text) for kind, text in page.evaluate(TRANSCRIPT)]


def wait_page(page: Page, expression: str, timeout: float = 30.0, what: str = "") -> Any:
    return wait_for(
        lambda: page.evaluate(expression), timeout=timeout, interval=0.05, what=what or expression
    )


def jpeg(width: int, height: int) -> bytes:
    image = Image.new("RGB", (width, height), (20, 40, 160))
    ImageDraw.Draw(image).ellipse((width // 4, height // 4, width // 2, height // 2), fill=(200, 200, 200))
    out = io.BytesIO()
    image.save(out, "JPEG", quality=85)
    return out.getvalue()


def b64(data: bytes) -> str:
    return base64.b64encode(data).decode()
