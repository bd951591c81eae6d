"""What the agent reports of its turns and sessions: a record on `metrics` (agents/metrics.py) and a
log line each. A failure and its reason are a report for monitors, never words on `response_text`
(which is the robot's speech and the conversation).

The runtime calls these from its one task with the state they report; this keeps none of its own.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from functools import partial

from by_your_command.agents.metrics import SessionMetrics, SessionOpenedMetrics, TurnMetrics
from by_your_command.agents.port import RobotPort
from by_your_command.agents.reply_audio import ReplyAudio
from by_your_command.agents.robot_runner import Publish
from by_your_command.agents.session import Session
from by_your_command.agents.turn import Turn

log = logging.getLogger(__name__)


class AgentReports:
    def __init__(
        self,
        agent_id: str,
        port: RobotPort,
        *,
        publish: Publish,
        now: Callable[[], float],
        conversation_id: Callable[[], str],
    ) -> None:
        """`conversation_id()`: the conversation now (the records name it)."""
        self._agent_id = agent_id
        self._port = port
        self._publish = publish
        self._now = now
        self._conversation_id = conversation_id

    def turn(
        self,
        turn: Turn,
        outcome: str,
        why: str,
        serial: int,
        session: Session | None,
        reply: ReplyAudio | None,
    ) -> None:
        """A turn ended (`why` it failed or was not delivered, "" if it did not); `serial` is the
        latest session's, `session` the one open (None: none), `reply` the latest spoken reply."""
        now = self._now()
        ended = turn.ended_at if turn.ended_at is not None else now
        first = None if turn.first_audio_at is None else round(1000.0 * (turn.first_audio_at - ended), 1)
        record = TurnMetrics(
            self._agent_id,
            self._conversation_id(),
            serial,
            turn.number,
            turn.kind,
            outcome,
            first,
            round(1000.0 * (now - ended), 1),
            turn.usage,
            session.provider.name if session is not None else "",
            why,
            _reply_stream(turn, reply),
        )
        log.log(
            logging.WARNING if why else logging.INFO,
            "agent %s: turn %d %s (%s)%s, first audio %s ms, reply %.0f ms, tokens in %d out %d",
            self._agent_id,
            turn.number,
            outcome,
            turn.kind,
            f": {why}" if why else "",
            first,
            record.reply_ms,
            turn.usage.input_tokens,
            turn.usage.output_tokens,
        )
        self._publish("metrics", partial(self._port.publish_metrics, record))

    def session_opened(self, session: Session) -> None:
        """Billing runs from here: monitors show the session before its first turn."""
        log.info("agent %s: session %d open (%s)", self._agent_id, session.serial, session.provider.name)
        opened = SessionOpenedMetrics(
            self._agent_id, self._conversation_id(), session.serial, session.provider.name
        )
        self._publish("metrics", partial(self._port.publish_metrics, opened))

    def session_closed(self, session: Session, reason: str, billed: float) -> None:
        """The session closed after `billed` s of connection (what the vendor bills)."""
        if session.opened_at is None:  # refused or never connected: the vendor bills nothing
            billed = 0.0
            log.info(
                "agent %s: session %d ended before it opened (%s)", self._agent_id, session.serial, reason
            )
        record = SessionMetrics(
            self._agent_id,
            self._conversation_id(),
            session.serial,
            round(billed, 3),
            session.turns,
            reason,
            session.usage,
            session.provider.name,
        )
        log.log(
            logging.INFO if session.opened_at is not None else logging.DEBUG,
            "agent %s: session %d closed (%s): billed %.1f s, %d turns, tokens in %d out %d",
            self._agent_id,
            session.serial,
            reason,
            billed,
            session.turns,
            session.usage.input_tokens,
            session.usage.output_tokens,
        )
        self._publish("metrics", partial(self._port.publish_metrics, record))


def _reply_stream(turn: Turn, reply: ReplyAudio | None) -> str:
    """The stream now playing the turn's reply (after any resume), "" if none was published."""
    if reply is None or reply.turn != turn.number or reply.stream_started_at is None:
        return ""
    return reply.stream_id
