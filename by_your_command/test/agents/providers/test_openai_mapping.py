"""OpenAI Realtime errors and usage → our typed events (pure functions, SDK models as input)."""

from __future__ import annotations

import pytest
from openai.types.realtime import RealtimeResponseUsage

from by_your_command.agents.events import ProviderError, Usage
from by_your_command.agents.providers.openai_realtime.errors import handshake_error, provider_error
from by_your_command.agents.providers.openai_realtime.events import usage_from

pytestmark = pytest.mark.unit


def test_usage_maps_every_token_kind_including_image_and_cached() -> None:
    usage = RealtimeResponseUsage.model_validate(
        {
            "input_tokens": 1234,
            "output_tokens": 60,
            "total_tokens": 1294,
            "input_token_details": {
                "text_tokens": 400,
                "audio_tokens": 70,
                "image_tokens": 764,
                "cached_tokens": 320,
                "cached_tokens_details": {"text_tokens": 320, "audio_tokens": 0, "image_tokens": 0},
            },
            "output_token_details": {"text_tokens": 12, "audio_tokens": 48},
        }
    )
    assert usage_from(usage) == Usage(
        input_text_tokens=400,
        input_audio_tokens=70,
        input_image_tokens=764,
        cached_input_tokens=320,
        output_text_tokens=12,
        output_audio_tokens=48,
    )
    assert usage_from(None) == Usage()


@pytest.mark.parametrize(
    ("code", "fatal"),
    [
        ("invalid_api_key", True),
        ("beta_api_shape_disabled", True),
        ("model_not_found", True),
        ("insufficient_quota", True),
        ("invalid_value", False),
        ("conversation_already_has_active_response", False),
        (None, False),
    ],
)
def test_errors_are_fatal_by_code(code: str | None, fatal: bool) -> None:
    error = provider_error(code, "server text")
    assert isinstance(error, ProviderError) and error.fatal is fatal


def test_cancel_not_active_is_harmless() -> None:
    assert (
        provider_error("response_cancel_not_active", "Cancellation failed: no active response found") is None
    )


@pytest.mark.parametrize(
    ("message", "retry"),
    [
        ("Rate limit reached. Please try again in 1.5s.", 1.5),
        ("try again in 250ms", 0.25),
        ("slow down", 1.0),
    ],
)
def test_rate_limits_ask_for_the_wait_the_server_names(message: str, retry: float) -> None:
    error = provider_error("rate_limit_exceeded", message)
    assert error is not None and not error.fatal and error.retry_after_s == pytest.approx(retry)


def test_auth_errors_never_repeat_the_servers_text_which_quotes_the_key() -> None:
    error = provider_error("invalid_api_key", "Incorrect API key provided: sk-pr***6789.")
    assert error is not None and "sk-pr" not in error.message and "OPENAI_API_KEY" in error.message


@pytest.mark.parametrize(
    ("status", "fatal"), [(401, True), (403, True), (404, True), (429, False), (503, False)]
)
def test_handshake_statuses(status: int, fatal: bool) -> None:
    error = handshake_error(status, "2")
    assert error.fatal is fatal
    if status == 429:
        assert error.retry_after_s == 2.0


@pytest.mark.parametrize(("header", "wait"), [("inf", 600.0), ("1e9", 600.0), ("nan", 0.0), ("-3", 0.0)])
def test_an_untrusted_retry_after_header_is_bounded(header: str, wait: float) -> None:
    """A 429's Retry-After is the server's word: "inf" must not stop the agent for good."""
    assert handshake_error(429, header).retry_after_s == wait
