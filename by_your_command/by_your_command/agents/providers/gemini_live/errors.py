"""Gemini Live close frames → ProviderError: which stop the agent, which back off, which are a lost
connection to retry.

Gemini reports errors as WebSocket close frames (protocols.md B.1): 1007 invalid argument (also an
invalid key, and a refused resumption), 1008 policy (no key, unknown model), 1011 internal (also
the ~58-minute "Deadline expired"). At setup, 1007/1008 cannot fix themselves: fatal, with our own
message for key problems (the key is never quoted).
"""

from __future__ import annotations

from by_your_command.agents.events import ProviderError

CLOSE_NORMAL = 1000
CLOSE_INVALID_ARGUMENT = 1007
CLOSE_POLICY = 1008
QUOTA_RETRY_AFTER_S = 10.0

KEY_MESSAGE = "Gemini refused the API key: set a valid key in GEMINI_API_KEY or GOOGLE_API_KEY"
MISSING_KEY_MESSAGE = "no Gemini API key: set GEMINI_API_KEY or GOOGLE_API_KEY"


def _about_key(reason: str) -> bool:
    lowered = reason.lower()
    return "api key" in lowered or "api_key" in lowered or "unregistered callers" in lowered


def _quota(reason: str) -> bool:
    lowered = reason.lower()
    return "quota" in lowered or "resource_exhausted" in lowered or "rate limit" in lowered


def setup_error(code: int, reason: str, model: str, resuming: bool) -> ProviderError | None:
    """The typed refusal for a close during setup; None for a plain lost connection (retry)."""
    if code in (CLOSE_INVALID_ARGUMENT, CLOSE_POLICY) and _about_key(reason):
        return ProviderError("invalid_api_key", f"{KEY_MESSAGE} (close {code})", fatal=True)
    if _quota(reason):
        return ProviderError(
            "quota_exceeded", f"Gemini quota or rate limit: {reason}", retry_after_s=QUOTA_RETRY_AFTER_S
        )
    if code == CLOSE_INVALID_ARGUMENT and resuming:
        return ProviderError("resume_refused", f"Gemini refused to resume the session: {reason}")
    if code == CLOSE_POLICY and ("not found" in reason.lower() or "not supported" in reason.lower()):
        return ProviderError(
            "model_not_found", f"Gemini has no live model {model!r} here: {reason}", fatal=True
        )
    if code in (CLOSE_INVALID_ARGUMENT, CLOSE_POLICY):
        return ProviderError(
            "invalid_setup", f"Gemini refused the session setup (close {code}): {reason}", fatal=True
        )
    return None


def session_closed(code: int, reason: str) -> ProviderError | None:
    """What a close in the middle of a session reports (None for a normal close). Never fatal: the
    runtime recycles the session; a refused setup on reconnect is what stops the agent."""
    if code == CLOSE_NORMAL:
        return None
    if _quota(reason):
        return ProviderError(
            "quota_exceeded", f"Gemini quota or rate limit: {reason}", retry_after_s=QUOTA_RETRY_AFTER_S
        )
    return ProviderError("server_closed", f"Gemini closed the session ({code} {reason})")


def handshake_error(status: int) -> ProviderError:
    """An HTTP status refusing the WebSocket upgrade (a wrong base URL, a proxy)."""
    if status in (401, 403):
        return ProviderError("invalid_api_key", f"{KEY_MESSAGE} (HTTP {status})", fatal=True)
    if status == 404:
        return ProviderError(
            "endpoint_not_found",
            "no Gemini Live endpoint at the configured URL (HTTP 404): check base_url and api_version",
            fatal=True,
        )
    if status == 429:
        return ProviderError(
            "rate_limit_exceeded", "Gemini rate limit (HTTP 429)", retry_after_s=QUOTA_RETRY_AFTER_S
        )
    return ProviderError("server_error", f"the Gemini endpoint refused the connection (HTTP {status})")
