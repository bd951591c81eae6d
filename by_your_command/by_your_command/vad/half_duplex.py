"""The VAD's half duplex (`echo_gate`): what the mic hears while the robot speaks is not the user,
except the rest of an utterance the user began before the robot started.

The gate (audio/echo_gate.py) keeps the robot's voice from becoming a prompt: nothing it says can
start an utterance, so it never answers itself. Cutting the user off is another matter: a reply
that starts while the user is mid-command (a late "I did not catch that" after a chat line) cut
the command to its first 0.45 s of 1.74 s. So an utterance open when the robot starts is heard on
to its own end, for at most `hold_ms`: the robot's voice may then trail at its end (the VAD cannot
tell the two voices apart), bounded, and no new utterance can start until the gate opens.
"""

from __future__ import annotations

from by_your_command.audio.echo_gate import EchoGate, captured

NS_PER_MS = 1_000_000


class HalfDuplexGate:
    def __init__(self, tail_ms: int, hold_ms: int) -> None:
        self._gate = EchoGate(tail_ms)
        self._hold_ns = hold_ms * NS_PER_MS
        self._hold_until: int | None = None  # the open utterance is heard until then

    @property
    def holding(self) -> bool:
        return self._hold_until is not None

    def set_speaking(self, speaking: bool, now_ns: int, mid_utterance: bool) -> bool:
        """Record a change of assistant_speaking; True when the robot starts to speak and the open
        utterance (if any) must end now. `mid_utterance`: the user is speaking, heard on."""
        if not self._gate.set_speaking(speaking, now_ns):
            return False
        if mid_utterance and self._hold_ns > 0:
            if self._hold_until is None:  # a second reply does not lengthen the hold
                self._hold_until = now_ns + self._hold_ns
            return False
        return True

    def admits(self, start_ns: int, samples: int, sample_rate: int, now_ns: int) -> bool:
        """Whether a block may hold the user: captured while the robot was silent (and past the
        tail), or during the hold of an utterance begun before it spoke."""
        if self._gate.admits(start_ns, samples, sample_rate, now_ns):
            return True
        if self._hold_until is None:
            return False
        start_ns, _ = captured(start_ns, samples, sample_rate, now_ns)
        return start_ns < self._hold_until

    def release(self) -> None:
        """The held utterance ended (on its own, or at the end of the hold)."""
        self._hold_until = None
