"""A deterministic stand-in for synthesized speech: same text, same samples, every run.

Each character gets `ms_per_char` of audio: letters and digits a voiced tone (pitch from the
character, a few harmonics, soft edges so there are no clicks), anything else silence, so words
are audibly separate and a played/truncated position maps back to a character.
"""

from __future__ import annotations

import numpy as np

from by_your_command.audio.pcm import Int16Array, float_to_int16

OUTPUT_RATE = 24_000  # the Realtime API's PCM is always 24 kHz mono s16le
BYTES_PER_MS = OUTPUT_RATE * 2 // 1000


def speech_ms(text: str, ms_per_char: int) -> int:
    return len(text) * ms_per_char


def speech_pcm(text: str, ms_per_char: int, rate: int = OUTPUT_RATE) -> bytes:
    samples_per_char = rate * ms_per_char // 1000
    t = np.arange(samples_per_char, dtype=np.float64) / rate
    ramp = min(samples_per_char // 4, rate // 200)  # 5 ms fade in/out
    envelope = np.ones(samples_per_char)
    if ramp:
        envelope[:ramp] = np.linspace(0.0, 1.0, ramp)
        envelope[-ramp:] = np.linspace(1.0, 0.0, ramp)
    blocks: list[Int16Array] = []
    silence = np.zeros(samples_per_char, dtype=np.int16)
    for char in text:
        if not char.isalnum():
            blocks.append(silence)
            continue
        pitch = 110.0 + (ord(char.lower()) % 32) * 4.0
        voiced = sum(np.sin(2 * np.pi * pitch * k * t) / k for k in (1, 2, 3))
        blocks.append(float_to_int16(0.25 * envelope * voiced))
    if not blocks:
        return b""
    return np.concatenate(blocks).astype("<i2").tobytes()
