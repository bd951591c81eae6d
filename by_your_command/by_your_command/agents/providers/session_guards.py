"""The checks every provider makes before it sends: its session is still open, and the audio it is
given is whole PCM16 samples. One place, so every provider refuses alike."""

from __future__ import annotations

from typing import TypeVar

from by_your_command.agents.provider import ProviderClosed

Handle = TypeVar("Handle")


def open_session(closed: bool, handle: Handle | None, session: str) -> Handle:
    """The handle of a session still open; a closed one is `ProviderClosed("<session> is closed")`."""
    if closed or handle is None:
        raise ProviderClosed(f"{session} is closed")
    return handle


def check_whole_samples(pcm: bytes) -> None:
    """PCM16 is two bytes a sample: an odd length is a caller's bug, refused before anything is sent."""
    if len(pcm) % 2:
        raise ValueError(f"PCM16 needs whole samples: {len(pcm)} bytes is odd")
