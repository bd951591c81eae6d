"""The bundled demo: a speech file (`demo_speech.wav`, built by `make_demo_speech.sh`) and the
pure parts of `byc demo` (what to run, how to narrate it). No ROS, nothing printed here."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

SPEECH_FILE = "demo_speech.wav"


def bundled_speech() -> Path:
    """The demo's speech file, wherever the package is (source checkout, colcon, wheel)."""
    path = Path(str(resources.files(__name__).joinpath(SPEECH_FILE)))
    if not path.is_file():
        raise FileNotFoundError(
            f"the demo speech file is missing: {path} (rebuild it with {path.parent / 'make_demo_speech.sh'})"
        )
    return path
