"""OpenAI account errors → ProviderError, for both speech APIs: the codes of the key, quota and
region (fatal), the rate limits (with the wait the server asks for) and the HTTP statuses of a
refused WebSocket upgrade. Each API adds its own codes (openai_realtime/errors.py, gpt_live/errors.py).

Server messages about keys quote part of the key ("Incorrect API key provided: sk-ab***yz"), so
auth errors get our own message and the server's text is never passed on.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Set

from by_your_command.agents.events import ProviderError

# Retrying cannot fix these: a person has to change the key, the model name or the account.
ACCOUNT_FATAL_CODES = frozenset(
    {
        "invalid_api_key",
        "model_not_found",
        "insufficient_quota",
        "account_deactivated",
        "permission_denied",
        "unsupported_country_region_territory",
    }
)
RATE_LIMIT_CODES = frozenset({"rate_limit_exceeded", "rate_limit_error"})
DEFAULT_RETRY_AFTER_S = 1.0
MAX_RETRY_AFTER_S = 600.0  # a header is untrusted: "inf" must not stop the agent for good

KEY_MESSAGE = "OpenAI refused the API key: set a valid key in OPENAI_API_KEY"
_TRY_AGAIN = re.compile(r"try again in (\d+(?:\.\d+)?)\s*(ms|s)\b", re.IGNORECASE)


def retry_after_from(message: str) -> float:
    """The wait the server asks for in its message ("Please try again in 1.2s"), else a default."""
    match = _TRY_AGAIN.search(message)
    if match is None:
        return DEFAULT_RETRY_AFTER_S
    value = float(match.group(1))
    return value / 1000 if match.group(2).lower() == "ms" else value


def account_error(
    code: str, message: str, fatal_codes: Set[str], own_messages: Mapping[str, str]
) -> ProviderError:
    """A server error by code: a rate limit backs off, a fatal code stops the agent; `own_messages`
    replace the server's text (which may quote the key)."""
    if code in RATE_LIMIT_CODES:
        return ProviderError(code, message, retry_after_s=retry_after_from(message))
    return ProviderError(code, own_messages.get(code, message), fatal=code in fatal_codes)


def handshake_error(
    status: int, retry_after_header: str | None, *, api: str, path: str, no_access_to: str
) -> ProviderError:
    """The typed error for an HTTP status refusing the WebSocket upgrade to `api` (its endpoint is
    `path` below /v1; `no_access_to`: what a 403 says the key's project cannot reach)."""
    if status == 401:
        return ProviderError("invalid_api_key", f"{KEY_MESSAGE} (HTTP 401)", fatal=True)
    if status == 403:
        return ProviderError(
            "permission_denied",
            f"OpenAI refused access (HTTP 403): the key's project has no access to {no_access_to}",
            fatal=True,
        )
    if status == 404:
        return ProviderError(
            "endpoint_not_found",
            f"no {api} endpoint at the configured URL (HTTP 404): check base_url / websocket_base_url "
            f"(it must end in /v1; the SDK appends {path})",
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
    return ProviderError("server_error", f"the {api} endpoint refused the connection (HTTP {status})")
