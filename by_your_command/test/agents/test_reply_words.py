"""ReplyWords on its own (agents/reply_words.py): where the model's words go — the context and
`response_text`, a command agent's to `response_cmd`, detections to `detections` and never on as
words. (Through the whole runtime: test_detections_runtime.py, test_turns.py.)"""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import Awaitable, Callable

import pytest
from fake_port import FakePort

from by_your_command.agents.config import AgentConfig, AgentRole, ContextSource
from by_your_command.agents.context import ContextStore
from by_your_command.agents.frames import FrameChoice
from by_your_command.agents.metrics import Counters
from by_your_command.agents.reply_words import ReplyWords

pytestmark = pytest.mark.unit

BOXES = 'a cup\n```json\n[{"box_2d": [100, 200, 500, 600], "label": "cup"}]\n```'


@dataclasses.dataclass
class Words:
    words: ReplyWords
    port: FakePort
    context: ContextStore
    counters: Counters
    cut: set[str]
    sends: list[tuple[str, Callable[[], Awaitable[None]]]]

    def published(self) -> list[tuple[str, object]]:
        """Run what was published, in order; the port's (kind, payload)."""

        async def run_all() -> None:
            for _, send in self.sends:
                await send()

        asyncio.run(run_all())
        self.sends.clear()
        return [(kind, payload) for _, kind, payload in self.port.published]

    def history(self) -> list[str]:
        return [turn.text for turn in self.context.history(0.0)]


def words_for(config: AgentConfig, old_conversation: bool = False) -> Words:
    port = FakePort()
    context = ContextStore(1000, 3600.0, 3600.0)
    context.new_conversation(0.0, 0.0)
    counters = Counters()
    cut: set[str] = set()
    sends: list[tuple[str, Callable[[], Awaitable[None]]]] = []
    words = ReplyWords(
        config,
        context,
        counters,
        FrameChoice(1.0),
        port,  # type: ignore[arg-type]
        publish=lambda what, send: sends.append((what, send)),
        now=lambda: 0.0,
        was_cut=cut.__contains__,
        old_conversation=lambda: old_conversation,
    )
    return Words(words, port, context, counters, cut, sends)


def test_a_reply_is_said_and_kept_with_a_cut_one_marked() -> None:
    w = words_for(AgentConfig(context_source=ContextSource.OWN))
    w.cut.add("r2")
    w.words.transcript("  Hello there. ", "r1")
    w.words.transcript("I was going to", "r2")
    w.words.transcript("   ", "r3")  # nothing said: nothing published or kept
    assert w.published() == [("text", "Hello there."), ("text", "I was going to")]
    assert w.history() == ["Hello there.", "I was going to [cut off by the user]"]


def test_words_of_an_old_conversation_are_said_but_not_kept() -> None:
    w = words_for(AgentConfig(context_source=ContextSource.OWN), old_conversation=True)
    w.words.text_reply("Hello.", "r1")
    assert w.published() == [("text", "Hello.")]
    assert w.history() == []


def test_a_command_agents_reply_is_its_command_unless_it_holds_unreadable_boxes() -> None:
    w = words_for(AgentConfig(role=AgentRole.COMMAND))
    w.words.text_reply(" pan@left ", "r1")
    w.words.text_reply('wave [{"box_2d": [1, 2', "r2")  # broken detection JSON: no command
    assert w.published() == [("cmd", "pan@left")]


def test_detections_go_to_their_topic_and_never_on_as_words() -> None:
    w = words_for(AgentConfig(detections=True))
    w.words.text_reply(BOXES, "r1")
    [(kind, report), (said_kind, text)] = w.published()
    assert (kind, said_kind) == ("detections", "text")
    assert [d.label for d in report.detections] == ["cup"]  # type: ignore[attr-defined]
    assert "box_2d" not in text
    assert w.counters.detections_published == 1


def test_detections_are_dropped_and_counted_when_not_asked_for() -> None:
    w = words_for(AgentConfig())
    w.words.transcript(BOXES, "r1")
    assert [kind for kind, _ in w.published()] == ["text"]
    assert w.counters.detections_dropped == 1
