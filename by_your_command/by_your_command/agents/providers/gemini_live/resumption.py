"""The newest Gemini session resumption handle of one agent, shared by the providers its factory
builds (a provider is one connection; resumption carries the conversation to the next one).

The server sends `sessionResumptionUpdate` at turn boundaries, often right after turnComplete
(which is why the provider reads the socket continuously: python-genai#2527). Handles are valid
for 2 h after the session ends; we count from receipt, with a margin. A handle belongs to the
runtime's conversation that made it: a session of another conversation (after a reset) never
resumes it, or the old server-side conversation would come back whole. Never share one store
between two agents (a dual setup has two conversations).
"""

from __future__ import annotations

import time
from collections.abc import Callable

HANDLE_TTL_S = 2 * 3600.0 - 300.0  # the server's 2 h, less a margin for clock and close delays


class ResumptionHandles:
    def __init__(self, ttl_s: float = HANDLE_TTL_S, clock: Callable[[], float] = time.monotonic) -> None:
        self._ttl_s, self._clock = ttl_s, clock
        self._handle: str | None = None
        self._conversation = ""
        self._received_at = 0.0

    def keep(self, handle: str, conversation_id: str) -> None:
        """A newer resumable handle replaces the older one; it continues `conversation_id` only."""
        self._handle, self._conversation, self._received_at = handle, conversation_id, self._clock()

    def usable(self, conversation_id: str) -> str | None:
        """The handle to resume `conversation_id` with, if any. A handle of another conversation is
        dropped: that conversation ended (a reset), and its server-side state must not come back."""
        if self._handle is not None and (
            conversation_id != self._conversation or self._clock() - self._received_at > self._ttl_s
        ):
            self._handle = None
        return self._handle

    def forget(self) -> None:
        """After a refused resume: the next session starts fresh (with text context)."""
        self._handle = None
