"""OpenAI Realtime errors → ProviderError, by code: which stop the agent, which back off, which are noise.

Server messages about keys quote part of the key ("Incorrect API key provided: sk-ab***yz"), so
auth errors get our own message and the server's text is never passed on.
"""

from __future__ import annotations

import re

from by_your_command.agents.events import ProviderError

# Retrying cannot fix these: a person has to change the key, the model name or the endpoint.
FATAL_CODES = frozenset(
    {
        "invalid_api_key",
        "beta_api_shape_disabled",
        "model_not_found",
        "insufficient_quota",
        "account_deactivated",
        "permission_denied",
        "unsupported_country_region_territory",
    }
)
# A cancel racing the end of a reply: the session is fine (protocols.md A.4).
HARMLESS_CODES = frozenset({"response_cancel_not_active"})
RATE_LIMIT_CODES = frozenset({"rate_limit_exceeded", "rate_limit_error"})
DEFAULT_RETRY_AFTER_S = 1.0

_KEY_MESSAGE = "OpenAI refused the API key: set a valid key in OPENAI_API_KEY"
_OWN_MESSAGES = {
    "invalid_api_key": _KEY_MESSAGE,
    "beta_api_shape_disabled": "the endpoint refused the legacy Realtime beta interface "
    "(an 'OpenAI-Beta: realtime=v1' header): this agent speaks GA; remove that header",
}
_TRY_AGAIN = re.compile(r"try again in (\d+(?:\.\d+)?)\s*(ms|s)\b", re.IGNORECASE)


def retry_after_from(message: str) -> float:
    """The wait the server asks for in its message ("Please try again in 1.2s"), else a default."""
    match = _TRY_AGAIN.search(message)
    if match is None:
        return DEFAULT_RETRY_AFTER_S
    value = float(match.group(1))
    return value / 1000 if match.group(2).lower() == "ms" else value


def provider_error(code: str | None, message: str) -> ProviderError | None:
    """The typed error for a server `error` (or a failed response's error); None for harmless ones."""
    code = code or "unknown_error"
    if code in HARMLESS_CODES:
        return None
    if code in RATE_LIMIT_CODES:
        return ProviderError(code, message, retry_after_s=retry_after_from(message))
    return ProviderError(code, _OWN_MESSAGES.get(code, message), fatal=code in FATAL_CODES)


def handshake_error(status: int, retry_after_header: str | None = None) -> ProviderError:
    """The typed error for an HTTP status refusing the WebSocket upgrade."""
    if status == 401:
        return ProviderError("invalid_api_key", f"{_KEY_MESSAGE} (HTTP 401)", fatal=True)
    if status == 403:
        return ProviderError(
            "permission_denied",
            "OpenAI refused access (HTTP 403): the key's project has no access to this model or region",
            fatal=True,
        )
    if status == 404:
        return ProviderError(
            "endpoint_not_found",
            "no Realtime endpoint at the configured URL (HTTP 404): check base_url / websocket_base_url "
            "(it must end in /v1; the SDK appends /realtime)",
            fatal=True,
        )
    if status == 429:
        retry = DEFAULT_RETRY_AFTER_S
        if retry_after_header:
            try:
                retry = max(0.0, float(retry_after_header))
            except ValueError:
                pass
        return ProviderError("rate_limit_exceeded", "OpenAI rate limit (HTTP 429)", retry_after_s=retry)
    return ProviderError("server_error", f"the Realtime endpoint refused the connection (HTTP {status})")
