"""GPT-Live errors → ProviderError, by code: which stop the agent, which back off, which are noise.

Server messages about keys quote part of the key ("Incorrect API key provided: sk-ab***yz"), so
auth errors get our own message and the server's text is never passed on.
"""

from __future__ import annotations

from by_your_command.agents.events import ProviderError
from by_your_command.agents.providers.openai_realtime.errors import DEFAULT_RETRY_AFTER_S, retry_after_from

# Retrying cannot fix these: a person has to change the key, the model name or the endpoint.
FATAL_CODES = frozenset(
    {
        "invalid_api_key",
        "model_not_found",
        "insufficient_quota",
        "account_deactivated",
        "permission_denied",
        "unsupported_country_region_territory",
        "unsupported_delegation",  # a response.* event without Responses delegation: our bug
    }
)
RATE_LIMIT_CODES = frozenset({"rate_limit_exceeded", "rate_limit_error"})
MAX_RETRY_AFTER_S = 600.0  # a header is untrusted: "inf" must not stop the agent for good

_KEY_MESSAGE = "OpenAI refused the API key: set a valid key in OPENAI_API_KEY"
_OWN_MESSAGES = {"invalid_api_key": _KEY_MESSAGE}


def provider_error(code: str | None, message: str) -> ProviderError:
    """The typed error for a server `error` event."""
    code = code or "unknown_error"
    if code in RATE_LIMIT_CODES:
        return ProviderError(code, message, retry_after_s=retry_after_from(message))
    return ProviderError(code, _OWN_MESSAGES.get(code, message), fatal=code in FATAL_CODES)


def start_refusal(code: str | None, message: str) -> ProviderError:
    """An `error` answering session.start: a refused session config will not fix itself (fatal)
    unless it is a rate limit, which only delays the next attempt."""
    error = provider_error(code, message)
    if error.retry_after_s is not None:
        return error
    return ProviderError(error.code, f"GPT-Live refused the session: {error.message}", fatal=True)


def handshake_error(status: int, retry_after_header: str | None = None) -> ProviderError:
    """The typed error for an HTTP status refusing the WebSocket upgrade."""
    if status == 401:
        return ProviderError("invalid_api_key", f"{_KEY_MESSAGE} (HTTP 401)", fatal=True)
    if status == 403:
        return ProviderError(
            "permission_denied",
            "OpenAI refused access (HTTP 403): the key's project has no access to GPT-Live or this region",
            fatal=True,
        )
    if status == 404:
        return ProviderError(
            "endpoint_not_found",
            "no GPT-Live endpoint at the configured URL (HTTP 404): check base_url / websocket_base_url "
            "(it must end in /v1; the SDK appends /live/sessions)",
            fatal=True,
        )
    if status == 429:
        retry = DEFAULT_RETRY_AFTER_S
        if retry_after_header:
            try:
                retry = min(max(0.0, float(retry_after_header)), MAX_RETRY_AFTER_S)  # NaN → 0
            except ValueError:
                pass
        return ProviderError("rate_limit_exceeded", "OpenAI rate limit (HTTP 429)", retry_after_s=retry)
    return ProviderError("server_error", f"the GPT-Live endpoint refused the connection (HTTP {status})")
