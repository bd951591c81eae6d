"""Full duplex (GPT-Live): the model hears the user over its own voice and decides itself when to
yield. The runtime does not judge barge-ins (no pause, no held audio), ends each utterance at once,
cuts the player when the model yields, and takes an unanswered utterance as the model's choice.
(Through the real provider and emulator: providers/test_gpt_live_provider.py.)"""

from __future__ import annotations

import asyncio
import json

import pytest
from fake_port import playing, running_agent, speak
from fake_provider import FakeFactory, FakeProvider, Script, spoken_reply
from test_robot_calls import CATALOG
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig, AgentRole, EchoMode
from by_your_command.agents.delegation import DelegatedCall, match_tool
from by_your_command.agents.events import (
    Interrupted,
    ResponseDone,
    ResponseStatus,
    ToolCall,
    Usage,
    UsageReport,
)
from by_your_command.agents.inputs import Attention, AttentionChanged, ToolCatalog
from by_your_command.agents.provider import ToolSpec
from by_your_command.agents.robot_tool import TOOL_NAME

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

CONFIG = AgentConfig(echo_mode=EchoMode.AEC, reply_timeout_s=3.0, pause_timeout_s=30.0)


def duplex(*scripts: Script) -> FakeFactory:
    def configure(provider: FakeProvider, _: int) -> None:
        provider.duplex = True  # type: ignore[attr-defined]

    return FakeFactory(*scripts, configure=configure)


def test_speech_over_a_reply_goes_to_the_model_at_once_and_its_yield_cuts_the_player() -> None:
    async def scenario() -> None:
        factory = duplex(spoken_reply("r1", seconds=2.0, pace_s=0.2), spoken_reply("r2", seconds=0.2))
        async with running_agent(CONFIG, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.3)
            [stream] = agent.port.streams()
            agent.port.push(playing(stream, 300))
            provider = factory.last
            audio_before = len(provider.audio)
            await speak(agent.port, 2, seconds=0.2, end=False)  # the user talks over the reply
            assert agent.port.of("pause") == []  # no judge of ours: the model decides
            assert len(provider.audio) > audio_before  # heard now, not held for a verdict
            provider.emit(Interrupted("r1"))  # the model stopped talking: it yielded
            await asyncio.sleep(0.001)
            assert agent.port.of("interruption") == [(stream, "model_yielded")]
            provider.emit(
                ResponseDone("r1", ResponseStatus.CANCELLED, reason="the model yielded to the user")
            )
            await speak(agent.port, 2, seconds=0.1)
            await asyncio.sleep(1.0)
            await agent.stop()
        outcomes = [(t.turn, t.outcome) for t in agent.port.turns()]
        assert (1, "interrupted") in outcomes
        assert agent.runtime.counters.barge_ins == 1 and agent.runtime.counters.false_barge_ins == 0

    run_virtual(scenario())


def test_an_utterance_ends_at_once_even_while_the_model_is_still_answering() -> None:
    async def scenario() -> None:
        factory = duplex(spoken_reply("r1", seconds=2.0, pace_s=0.3))
        async with running_agent(CONFIG, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.2)  # r1 is being generated
            await speak(agent.port, 2, seconds=0.3)  # "... and the kitchen too"
            provider = factory.last
            ends = [i for i, name in enumerate(provider.names()) if name == "end_of_turn"]
            assert len(ends) == 2  # the second end is the model's now: it hears the user stop
            await asyncio.sleep(3.0)
            await agent.stop()
        assert [t.outcome for t in agent.port.turns()] == ["completed", "completed"]

    run_virtual(scenario())


def test_an_unanswered_utterance_is_the_models_choice_not_a_lost_session() -> None:
    async def scenario() -> None:
        factory = duplex()  # the model says nothing to "uh-huh"
        async with running_agent(CONFIG, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(CONFIG.reply_timeout_s + 1.0)
            await agent.stop()
        assert [(t.turn, t.outcome) for t in agent.port.turns()] == [(1, "unanswered")]
        assert len(factory.created) == 1  # no reconnect, no replay
        assert agent.runtime.counters.turns_failed == 0

    run_virtual(scenario())


def test_billed_session_seconds_are_summed_into_the_sessions_usage() -> None:
    async def scenario() -> None:
        factory = duplex(spoken_reply("r1", seconds=0.2))
        async with running_agent(CONFIG, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.5)
            provider = factory.last
            provider.emit(UsageReport(Usage(session_s=1.5)))
            provider.emit(UsageReport(Usage(session_s=0.5)))
            await asyncio.sleep(0.1)
            session = agent.runtime._session
            assert session is not None and session.usage.session_s == pytest.approx(2.0)
            await agent.stop()

    run_virtual(scenario())


# ---- delegation: the user's words → one of the robot's tools ------------------------------------


def delegation(words: str, call_id: str = "dlg_1") -> Script:
    """A GPT-Live client delegation: no function, the user's words as the command (gpt_live/events.py)."""
    return [
        (0.1, ToolCall("r1", call_id, TOOL_NAME, json.dumps({"command": words}))),
        (0.0, ResponseDone("r1", ResponseStatus.COMPLETED)),
    ]


@pytest.mark.parametrize(
    ("words", "goal"), [("robot, please go to the kitchen", True), ("don't go to the kitchen", False)]
)
def test_a_delegation_in_a_tools_declared_words_runs_that_tool(words: str, goal: bool) -> None:
    async def scenario() -> None:
        factory = duplex(delegation(words))
        config = AgentConfig(role=AgentRole.TOOLS, echo_mode=EchoMode.AEC, reply_timeout_s=5.0)
        async with running_agent(config, factory) as agent:
            agent.port.push(ToolCatalog(json.dumps(CATALOG)))
            await asyncio.sleep(0.1)
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            if goal:  # the named place, never numbers from a model
                [(_, action, _, sent)] = agent.port.of("goal")
                assert action == "/navigate_to_pose" and sent["pose"]["pose"]["position"]["x"] == 3.0
            else:  # not the phrase, only words around it: the command processor judges the words
                assert agent.port.of("goal") == []
                assert agent.port.requests() == [words]
            await agent.stop()

    run_virtual(scenario())


def test_a_delegation_matches_only_a_whole_declared_phrase() -> None:
    spec = ToolSpec("go_to", "", {}, spoken=(("go to the kitchen", '{"place": "kitchen"}'),))
    dock = ToolSpec("dock", "", {}, spoken=(("dock", "{}"),))
    assert match_tool("Go to the kitchen.", [spec]) == DelegatedCall("go_to", '{"place": "kitchen"}')
    assert match_tool("hey robot could you please go to the kitchen now thanks", [spec, dock]) is not None
    assert match_tool("could you dock please", [spec, dock]) == DelegatedCall("dock", "{}")
    for not_it in ("don't go to the kitchen", "go to the kitchen and dance", "kitchen", "please", ""):
        assert match_tool(not_it, [spec, dock]) is None
    twice = ToolSpec("undock", "", {}, spoken=(("dock", '{"undo": true}'),))
    assert match_tool("dock", [dock, twice]) is None  # said for two calls: neither is surely meant


def test_sleep_and_mute_mute_the_models_input() -> None:
    async def scenario() -> None:
        factory = duplex(spoken_reply("r1", seconds=0.2))
        async with running_agent(CONFIG, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.5)
            provider = factory.last
            muting: list[bool] = []

            async def mute() -> None:
                muting.append(True)

            async def unmute() -> None:
                muting.append(False)

            provider.mute, provider.unmute = mute, unmute  # type: ignore[attr-defined]
            for state in (Attention.ASLEEP, Attention.MUTED, Attention.AWAKE, Attention.AWAKE):
                agent.port.push(AttentionChanged(state))
                await asyncio.sleep(0.01)
            assert muting == [True, False]  # asleep then muted is still muted: one mute, one unmute
            await agent.stop()

    run_virtual(scenario())
