"""The cost estimate: tokens and session time priced per provider (config/monitor.yaml)."""

from __future__ import annotations

from dataclasses import dataclass, fields

from by_your_command.monitor.records import Tokens

PER_MILLION = 1_000_000.0


@dataclass(frozen=True)
class Prices:
    """One provider's prices: per million tokens of each kind, and per minute of open session."""

    input_text: float = 0.0
    input_audio: float = 0.0
    input_image: float = 0.0
    cached_input: float = 0.0  # cached input tokens are also counted in their kind; this is the discount
    output_text: float = 0.0
    output_audio: float = 0.0
    session_minute: float = 0.0

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 1e9:
                raise ValueError(f"{item.name}: a price must be a number 0..1e9, got {value!r}")


def estimate_cost(tokens: Tokens, billed_s: float, prices: Prices) -> float:
    """What `tokens` and `billed_s` seconds of session cost at `prices`.

    Vendors report cached input tokens inside the input counts and bill them at the cached price
    instead: they are taken off the dearest input kind they can belong to (audio, then text), so a
    cached token is never priced twice."""
    cached = min(tokens.cached_input, tokens.input_audio + tokens.input_text)
    cached_audio = min(cached, tokens.input_audio)
    cached_text = cached - cached_audio
    per_token = (
        (tokens.input_text - cached_text) * prices.input_text
        + (tokens.input_audio - cached_audio) * prices.input_audio
        + tokens.input_image * prices.input_image
        + cached * prices.cached_input
        + tokens.output_text * prices.output_text
        + tokens.output_audio * prices.output_audio
    ) / PER_MILLION
    return per_token + billed_s / 60.0 * prices.session_minute
