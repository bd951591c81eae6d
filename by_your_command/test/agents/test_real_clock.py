"""The scheduler on the real clock (asyncio's own loop, LoopClock): deadlines computed from `now()`
while `now()` moves on can never be seen on virtual time, where time stands still between timers.
Each wait is on a condition; a frozen scheduler fails the wait instead of hanging the test."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest
from fake_port import FakePort
from fake_provider import FakeFactory, spoken_reply

from by_your_command.agents.config import AgentConfig
from by_your_command.agents.events import SessionEnding
from by_your_command.agents.inputs import ConversationReset, PlaybackStatus, PromptText
from by_your_command.agents.runtime import AgentRuntime

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


async def until(condition: Callable[[], bool], what: str, timeout_s: float = 10.0) -> None:
    loop = asyncio.get_running_loop()
    give_up = loop.time() + timeout_s
    while not condition():
        if loop.time() > give_up:
            raise AssertionError(f"timed out waiting for {what}")
        await asyncio.sleep(0.01)


class RealClockAgent:
    def __init__(self, config: AgentConfig, factory: FakeFactory) -> None:
        self.port = FakePort()
        self.factory = factory
        self.runtime = AgentRuntime(config, "You are a test robot.", self.port, factory)  # LoopClock
        self.task = asyncio.create_task(self.runtime.run())

    def completed(self) -> int:
        return sum(turn.outcome == "completed" for turn in self.port.turns())

    def close_reasons(self) -> list[str]:
        return [session.close_reason for session in self.port.sessions()]

    def finish_playback(self) -> None:
        """What the player says once the reply's last stream has played."""
        stream = self.port.voice()[-1].stream_id
        self.port.push(PlaybackStatus(stream, 200, queued_ms=0, speaking=False, finished=True))

    async def stop(self) -> None:
        """stop() must be heard at once: a frozen scheduler never takes it from its queue."""
        self.runtime.stop()
        await until(self.task.done, "the agent to stop", timeout_s=5.0)
        self.task.result()


def test_a_go_away_while_idle_closes_the_session_and_the_next_turn_is_answered() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", 0.2), spoken_reply("r2", 0.2))
        agent = RealClockAgent(AgentConfig(pause_timeout_s=100.0), factory)
        agent.port.push(PromptText("hello"))
        await until(lambda: agent.completed() == 1, "the first reply")
        agent.finish_playback()
        factory.last.emit(SessionEnding("goAway", 30.0))
        await until(lambda: agent.close_reasons() != [], "the announced session to close")
        assert agent.close_reasons() == ["the provider is ending the session (goAway)"]
        agent.port.push(PromptText("are you there"))
        await until(lambda: agent.completed() == 2, "the reply on a new session")
        await agent.stop()
        assert len(factory.created) == 2

    asyncio.run(scenario())


def test_a_reset_while_a_reply_is_made_starts_the_next_turn_clean_on_a_new_session() -> None:
    async def scenario() -> None:
        factory = FakeFactory(
            spoken_reply("r1", 1.0, text="once upon a time", pace_s=0.1), spoken_reply("r2", 0.2)
        )
        agent = RealClockAgent(AgentConfig(pause_timeout_s=100.0), factory)
        agent.port.push(PromptText("tell me a story"))
        await until(lambda: agent.port.voice() != [], "the reply to start")
        agent.port.push(ConversationReset("fresh"))
        await until(lambda: agent.close_reasons() != [], "the old conversation's session to close")
        assert agent.close_reasons() == ["new conversation (external reset)"]
        assert [turn.outcome for turn in agent.port.turns()] == ["completed"]  # the reply was not cut
        assert agent.runtime.context.history(0.0) == ()  # nothing of the old conversation
        agent.port.push(PromptText("hello again"))
        await until(lambda: agent.completed() == 2, "the reply in the new conversation")
        await agent.stop()
        new = factory.created[1].setup
        assert new is not None and new.history == () and new.conversation_id == "fresh"

    asyncio.run(scenario())
