"""A turn the provider refuses (its audio too short to commit) fails at once and blocks nothing.

Found by bench/soak.py: a 64 ms fragment the VAD cut at the echo gate was refused by the OpenAI
provider, the runtime waited for a reply that could never come, lost the session at the reply
timeout, replayed the same fragment on the next session, and every later utterance queued behind it.
"""

from __future__ import annotations

import asyncio

import pytest
from fake_port import running_agent, speak
from fake_provider import FakeFactory, spoken_reply
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig
from by_your_command.agents.events import ProviderError

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

REFUSED = ProviderError("input_audio_buffer_commit_empty", "utterance of 64 ms not sent", refuses_turn=True)


def test_a_refused_turn_fails_now_and_the_next_turn_is_answered_on_the_same_session() -> None:
    async def scenario() -> None:
        factory = FakeFactory([(0.0, REFUSED)], spoken_reply("r2", 0.3))
        async with running_agent(AgentConfig(reply_timeout_s=20.0), factory) as agent:
            await speak(agent.port, 1, seconds=0.1)
            await asyncio.sleep(1.0)  # far less than the reply timeout
            assert [(t.turn, t.outcome) for t in agent.port.turns()] == [(1, "failed")]
            await speak(agent.port, 2, seconds=0.5)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert [(t.turn, t.outcome) for t in agent.port.turns()] == [(1, "failed"), (2, "completed")]
        assert len(factory.created) == 1  # the refusal did not cost the session
        assert factory.created[0].names().count("end_of_turn") == 2  # the refused turn was not replayed
        assert agent.runtime.counters.turns_failed == 1

    run_virtual(scenario())


def test_an_error_that_does_not_refuse_the_turn_leaves_it_waiting_for_its_reply() -> None:
    async def scenario() -> None:
        noise = ProviderError("transcription_failed", "input transcription failed")
        factory = FakeFactory([(0.0, noise), *spoken_reply("r1", 0.3, first_after_s=0.5)])
        async with running_agent(AgentConfig(), factory) as agent:
            await speak(agent.port, 1, seconds=0.5)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert [(t.turn, t.outcome) for t in agent.port.turns()] == [(1, "completed")]

    run_virtual(scenario())
