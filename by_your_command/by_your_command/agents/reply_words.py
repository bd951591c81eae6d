"""What the model says in words, and where it goes: its speech's transcript and its text replies to
the context and `response_text` (a command agent's to `response_cmd`), object detections in them to
`detections` (never on as words). The runtime owns it and calls it from its one task; what it needs
of the runtime is handed in explicitly."""

from __future__ import annotations

import logging
from collections.abc import Callable
from functools import partial

from by_your_command.agents.config import AgentConfig, AgentRole, ContextSource
from by_your_command.agents.context import ContextStore
from by_your_command.agents.detections import extract
from by_your_command.agents.frames import FrameChoice
from by_your_command.agents.metrics import Counters
from by_your_command.agents.port import DetectionReport, RobotPort
from by_your_command.agents.provider import Role
from by_your_command.agents.robot_runner import Publish

log = logging.getLogger(__name__)


class ReplyWords:
    def __init__(
        self,
        config: AgentConfig,
        context: ContextStore,
        counters: Counters,
        frames: FrameChoice,
        port: RobotPort,
        *,
        publish: Publish,
        now: Callable[[], float],
        was_cut: Callable[[str], bool],
        old_conversation: Callable[[], bool],
    ) -> None:
        """`was_cut(response_id)`: a barge-in cut that reply; `old_conversation()`: the session
        serves a conversation already reset (its words are not kept)."""
        self._config = config
        self._context = context
        self._counters = counters
        self._frames = frames
        self._port = port
        self._publish = publish
        self._now = now
        self._was_cut = was_cut
        self._old_conversation = old_conversation

    def transcript(self, text: str, response_id: str) -> None:
        """The final transcript of a spoken reply."""
        rest, _ = self._take_detections(text)
        self.said(rest, response_id)

    def text_reply(self, text: str, response_id: str) -> None:
        """A final text reply: said, or for a command agent its command (never unreadable box JSON)."""
        config = self._config
        rest, unreadable = self._take_detections(text)
        if config.role is not AgentRole.COMMAND:
            self.said(rest, response_id)
        elif unreadable:  # box JSON we could not read is still no command
            log.warning(
                "agent %s: a reply mentions box_2d but holds no readable detection: not routed",
                config.agent_id,
            )
        elif rest.strip():
            self._publish("response_cmd", partial(self._port.publish_cmd, rest.strip()))

    def said(self, text: str, response_id: str) -> None:
        text = text.strip()
        if not text:
            return
        if self._config.context_source is ContextSource.OWN and not self._old_conversation():
            heard = f"{text} [cut off by the user]" if self._was_cut(response_id) else text
            self._context.add(Role.ASSISTANT, heard, self._now())
        self._publish("response_text", partial(self._port.publish_text, text))

    def _take_detections(self, text: str) -> tuple[str, bool]:
        """Object detections in a reply go to `detections`, never on: the rest of the text, and
        whether it still holds detection JSON that could not be read."""
        config = self._config
        found = extract(text)
        if not found.found:
            return text, False
        self._counters.detections_refused += found.refused
        if found.detections and config.detections and config.topics.detections:
            report = DetectionReport(config.agent_id, found.detections, self._frames.shown())
            self._counters.detections_published += 1
            self._publish("detections", partial(self._port.publish_detections, report))
        elif found.detections:
            self._counters.detections_dropped += len(found.detections)
            log.info(
                "agent %s: %d detection(s) dropped (set detections: true to publish them)",
                config.agent_id,
                len(found.detections),
            )
        if found.refused:
            log.warning("agent %s: %d detection(s) refused as unusable", config.agent_id, found.refused)
        return found.text, found.unparsed
