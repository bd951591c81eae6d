"""OpenAI Realtime errors → ProviderError, by code: which stop the agent, which back off, which are
noise. The account's codes and the handshake are OpenAI's (openai_common/errors.py); here what only
Realtime says: the legacy beta shape refused, a cancel racing a reply's end."""

from __future__ import annotations

from by_your_command.agents.events import ProviderError
from by_your_command.agents.providers.openai_common import errors as account
from by_your_command.agents.providers.openai_common.errors import KEY_MESSAGE

FATAL_CODES = account.ACCOUNT_FATAL_CODES | {"beta_api_shape_disabled"}
# A cancel racing the end of a reply: the session is fine (protocols.md A.4).
HARMLESS_CODES = frozenset({"response_cancel_not_active"})

_OWN_MESSAGES = {
    "invalid_api_key": KEY_MESSAGE,
    "beta_api_shape_disabled": "the endpoint refused the legacy Realtime beta interface "
    "(an 'OpenAI-Beta: realtime=v1' header): this agent speaks GA; remove that header",
}


def provider_error(code: str | None, message: str) -> ProviderError | None:
    """The typed error for a server `error` (or a failed response's error); None for harmless ones."""
    code = code or "unknown_error"
    if code in HARMLESS_CODES:
        return None
    return account.account_error(code, message, FATAL_CODES, _OWN_MESSAGES)


def handshake_error(status: int, retry_after_header: str | None = None) -> ProviderError:
    """The typed error for an HTTP status refusing the WebSocket upgrade."""
    return account.handshake_error(
        status, retry_after_header, api="Realtime", path="/realtime", no_access_to="this model or region"
    )
