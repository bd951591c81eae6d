"""When the provider session closes: silence costs nothing, and no session reaches its limit.

- After `pause_timeout_s` without activity (the runtime closes it only when idle).
- Before its age limit (ours or the provider's, whichever is lower, less a margin): at the next
  turn boundary, and before a new turn at the latest.
- At the next boundary once asked: the provider announced its end (`provider_ends`), or the session
  became unfit for what comes next (`recycle`: new conversation, changed tools, a stop's audio in
  its input).
The runtime owns it (the scheduler's single owner of state) and asks it for reasons and deadlines.
"""

from __future__ import annotations

from typing import Protocol

ROTATION = "rotation before the limit"


class _Provider(Protocol):
    @property
    def max_session_s(self) -> float: ...


class _Session(Protocol):
    @property
    def opened_at(self) -> float | None: ...

    @property
    def provider(self) -> _Provider: ...

    def age(self, now: float) -> float: ...


class SessionEnd:
    def __init__(self, pause_timeout_s: float, max_session_s: float, rotation_margin_s: float) -> None:
        self._pause_timeout_s = pause_timeout_s
        self._max_session_s = max_session_s
        self._rotation_margin_s = rotation_margin_s
        self.provider_ending = ""  # the provider announced its end: rotate at the next boundary
        self.recycling = ""  # close the session at the next boundary, for this reason
        # When either was set: the close is due from then on. A fixed time, never now(): a
        # deadline read again after `now` was taken is never due, and the loop froze.
        self._asked_at = 0.0

    @property
    def asked(self) -> str:
        """Why the session closes at the next boundary ("" if nothing asked for it)."""
        return self.provider_ending or self.recycling

    def provider_ends(self, reason: str, now: float) -> None:
        self._ask(now)
        self.provider_ending = reason

    def recycle(self, reason: str, now: float, replace: bool = False) -> None:
        """Close at the next boundary for `reason` (the first reason given stays, unless `replace`)."""
        self._ask(now)
        self.recycling = reason if replace else self.recycling or reason

    def _ask(self, now: float) -> None:
        if not self.asked:
            self._asked_at = now

    def closed(self) -> None:
        self.provider_ending = self.recycling = ""

    def rotation_age(self, session: _Session | None) -> float:
        """The age at which a session is rotated: below the lower limit by a margin."""
        limit = self._max_session_s
        if session is not None:
            limit = min(limit, session.provider.max_session_s)
        margin = self._rotation_margin_s if self._rotation_margin_s < limit else 0.1 * limit
        return limit - margin

    def rotation_due(self, session: _Session | None, now: float) -> bool:
        return (
            session is not None
            and session.opened_at is not None
            and session.age(now) >= self.rotation_age(session)
        )

    def close_at(self, session: _Session | None, last_activity: float) -> float:
        """When an idle session closes."""
        if self.asked:
            return self._asked_at
        close_at = last_activity + self._pause_timeout_s
        if session is not None and session.opened_at is not None:
            close_at = min(close_at, session.opened_at + self.rotation_age(session))
        return close_at

    def reason(self, session: _Session | None, now: float) -> str:
        """Why an idle session closes now."""
        if self.asked:
            return self.asked
        if self.rotation_due(session, now):
            return ROTATION
        return f"pause of {self._pause_timeout_s:g} s"
