"""GPT-Live errors → ProviderError, by code: which stop the agent, which back off, which are noise.
The account's codes and the handshake are OpenAI's (openai_common/errors.py); here what only
GPT-Live says: a delegation mode we did not ask for, a refused session.start."""

from __future__ import annotations

from by_your_command.agents.events import ProviderError
from by_your_command.agents.providers.openai_common import errors as account
from by_your_command.agents.providers.openai_common.errors import KEY_MESSAGE

# a response.* event without Responses delegation: our bug, retrying repeats it
FATAL_CODES = account.ACCOUNT_FATAL_CODES | {"unsupported_delegation"}

_OWN_MESSAGES = {"invalid_api_key": KEY_MESSAGE}


def provider_error(code: str | None, message: str) -> ProviderError:
    """The typed error for a server `error` event."""
    return account.account_error(code or "unknown_error", message, FATAL_CODES, _OWN_MESSAGES)


def start_refusal(code: str | None, message: str) -> ProviderError:
    """An `error` answering session.start: a refused session config will not fix itself (fatal)
    unless it is a rate limit, which only delays the next attempt."""
    error = provider_error(code, message)
    if error.retry_after_s is not None:
        return error
    return ProviderError(error.code, f"GPT-Live refused the session: {error.message}", fatal=True)


def handshake_error(status: int, retry_after_header: str | None = None) -> ProviderError:
    """The typed error for an HTTP status refusing the WebSocket upgrade."""
    return account.handshake_error(
        status,
        retry_after_header,
        api="GPT-Live",
        path="/live/sessions",
        no_access_to="GPT-Live or this region",
    )
