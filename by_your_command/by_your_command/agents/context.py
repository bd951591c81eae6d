"""The conversation's memory: its id and its text transcript, bounded by tokens and age.

Carried into every new provider session as `SessionSetup.history`, so closing a session to save
money does not make the robot forget. Tokens are approximated as chars / 4 (no tokenizer needed);
the newest turns that fit are kept. A new conversation (inactivity, or an external reset) clears it.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

from by_your_command.agents.provider import HistoryTurn, Role


def approx_tokens(text: str) -> int:
    return (len(text) + 3) // 4


@dataclass(frozen=True)
class _Entry:
    role: Role
    text: str
    at: float  # monotonic seconds


class ContextStore:
    def __init__(self, max_tokens: int, max_age_s: float, conversation_timeout_s: float) -> None:
        self.max_tokens = max_tokens
        self.max_age_s = max_age_s
        self.conversation_timeout_s = conversation_timeout_s
        self._turns: deque[_Entry] = deque()
        self._tokens = 0
        self.conversation_id = ""
        self._serial = 0
        self._last_activity: float | None = None

    def new_conversation(self, now: float, wall: float, conversation_id: str = "") -> str:
        """Forget the transcript and start a new id (the given one, or a fresh one)."""
        self._serial += 1
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(wall))
        self.conversation_id = conversation_id or f"conv-{stamp}-{self._serial}"
        self._turns.clear()
        self._tokens = 0
        self._last_activity = now
        return self.conversation_id

    @property
    def serial(self) -> int:
        """Counts conversations: tells a new one from the old even when a reset reuses its id."""
        return self._serial

    def expired(self, now: float) -> bool:
        """True when the conversation has been idle longer than its timeout."""
        return self._last_activity is not None and now - self._last_activity >= self.conversation_timeout_s

    def expires_at(self) -> float | None:
        return None if self._last_activity is None else self._last_activity + self.conversation_timeout_s

    def touch(self, now: float) -> None:
        self._last_activity = now

    def add(self, role: Role, text: str, now: float) -> None:
        text = text.strip()
        if not text:
            return
        if approx_tokens(text) > self.max_tokens:  # one huge turn: keep its end, not nothing
            text = "…" + text[-(4 * self.max_tokens - 4) :]
        self._turns.append(_Entry(role, text, now))
        self._tokens += approx_tokens(text)
        self._last_activity = now
        self._trim(now)

    def add_user_before_reply(self, text: str, now: float, committed_at: float) -> None:
        """A user transcript that arrived after the reply to it began (transcription is slower than
        the reply): it goes before the assistant turns added since the user turn was committed."""
        self.add(Role.USER, text, now)
        if not text.strip():
            return
        entry = self._turns.pop()
        position = len(self._turns)
        while position > 0 and self._turns[position - 1].role is Role.ASSISTANT:
            if self._turns[position - 1].at < committed_at:
                break
            position -= 1
        self._turns.insert(position, entry)

    def last_user_text(self) -> str:
        """What the user said last ("" if nothing is kept)."""
        return next((entry.text for entry in reversed(self._turns) if entry.role is Role.USER), "")

    def history(self, now: float) -> tuple[HistoryTurn, ...]:
        self._trim(now)
        return tuple(HistoryTurn(entry.role, entry.text) for entry in self._turns)

    @property
    def tokens(self) -> int:
        return self._tokens

    def _trim(self, now: float) -> None:
        while self._turns and (self._tokens > self.max_tokens or now - self._turns[0].at > self.max_age_s):
            dropped = self._turns.popleft()
            self._tokens -= approx_tokens(dropped.text)
