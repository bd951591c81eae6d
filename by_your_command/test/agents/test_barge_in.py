"""Barge-in: the player is cut at the onset; real speech truncates the reply at played_ms, noise
resumes it as a new stream from where it was cut; half duplex and command agents never cut."""

from __future__ import annotations

import asyncio

import pytest
from fake_port import playing, running_agent, speak
from fake_provider import FakeFactory, spoken_reply
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig, AgentRole, EchoMode
from by_your_command.agents.inputs import PlaybackStatus, VoiceActivity
from by_your_command.agents.runtime import RECENT_CUTS

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

DUPLEX = AgentConfig(echo_mode=EchoMode.AEC, min_barge_in_ms=400, barge_in_window_s=1.5)


async def reply_playing(agent, played_ms: int) -> str:  # type: ignore[no-untyped-def]
    """A first turn whose 2 s reply is generated at once and is now playing at `played_ms`."""
    await speak(agent.port, 1, seconds=0.3)
    await asyncio.sleep(0.5)
    [stream] = agent.port.streams()
    agent.port.push(playing(stream, played_ms))
    await asyncio.sleep(0.001)
    return stream


def test_real_barge_in_cuts_the_player_first_then_truncates_at_the_played_ms() -> None:
    async def scenario() -> None:
        # r1 is generated in real time, so it is still being generated when the user barges in
        factory = FakeFactory(spoken_reply("r1", seconds=2.0, pace_s=0.2), spoken_reply("r2", seconds=0.2))
        async with running_agent(DUPLEX, factory) as agent:
            stream = await reply_playing(agent, 700)
            provider = factory.last
            calls_before = len(provider.calls)
            agent.port.push(VoiceActivity(True))
            await asyncio.sleep(0.001)
            # the interruption is out before the provider heard anything about it
            assert agent.port.of("interruption") == [(stream, "barge_in")]
            assert len(provider.calls) == calls_before
            agent.port.push(PlaybackStatus(stream, 760, interrupted=True))  # the player froze played_ms
            published_at_cut = len(agent.port.stream_audio(stream))
            await speak(agent.port, 2, seconds=1.0)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert len(agent.port.stream_audio(stream)) == published_at_cut  # nothing more of the cut reply
        names = provider.names()
        interrupt = names.index("interrupt")
        assert provider.calls[interrupt][1] == ("r1", "item-r1", 760)
        # the new utterance's audio follows the interrupt (held during the window, none lost)
        first_new_audio = next(i for i, n in enumerate(names) if n == "audio" and i > interrupt)
        assert first_new_audio > interrupt
        assert names.count("end_of_turn") == 2
        assert len(provider.audio) == 2 * (int(0.3 * 24000) + int(1.0 * 24000))
        assert [t.outcome for t in agent.port.turns()] == ["interrupted", "completed"]
        assert agent.runtime.counters.barge_ins == 1 and agent.runtime.counters.false_barge_ins == 0
        assert agent.runtime.context.history(0)[0].text == "hello there [cut off by the user]"

    run_virtual(scenario())


def test_false_barge_in_resumes_the_unplayed_remainder_as_a_new_stream() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0, chunk_s=0.2))
        async with running_agent(DUPLEX, factory) as agent:
            stream = await reply_playing(agent, 500)
            agent.port.push(VoiceActivity(True))
            agent.port.push(PlaybackStatus(stream, 500, interrupted=True))
            await speak(agent.port, 2, seconds=0.2)  # a cough: shorter than min_barge_in_ms
            await asyncio.sleep(1.0)
            await agent.stop()
        provider = factory.last
        assert "interrupt" not in provider.names()
        assert provider.names().count("end_of_turn") == 1  # the cough was never committed
        assert len(provider.audio) == 2 * int(0.3 * 24000)  # nor sent
        first, resumed = agent.port.streams()
        assert first == stream
        whole = agent.port.stream_audio(first)
        assert agent.port.stream_audio(resumed) == whole[2 * int(0.5 * 24000) :]
        assert agent.port.voice()[-1].stream_id == resumed and agent.port.voice()[-1].end_of_stream
        assert agent.runtime.counters.false_barge_ins == 1

    run_virtual(scenario())


def test_an_onset_without_speech_is_false_after_the_window() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0))
        async with running_agent(DUPLEX, factory) as agent:
            stream = await reply_playing(agent, 300)
            agent.port.push(VoiceActivity(True))  # a VAD blip: no utterance follows
            await asyncio.sleep(2.0)
            await agent.stop()
        assert agent.port.of("interruption") == [(stream, "barge_in")]
        assert len(agent.port.streams()) == 2
        assert agent.runtime.counters.false_barge_ins == 1

    run_virtual(scenario())


def test_barge_in_works_after_generation_ended_from_playback_status() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0), spoken_reply("r2", seconds=0.2))
        async with running_agent(DUPLEX, factory) as agent:
            stream = await reply_playing(agent, 100)
            assert agent.port.turns()[0].outcome == "completed"  # generation is over
            await asyncio.sleep(1.0)
            agent.port.push(playing(stream, 1100))
            await speak(agent.port, 2, seconds=0.8)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert agent.port.of("interruption") == [(stream, "barge_in")]
        assert ("interrupt", ("r1", "item-r1", 1100)) in factory.last.calls

    run_virtual(scenario())


@pytest.mark.parametrize(
    "config",
    [AgentConfig(echo_mode=EchoMode.GATE), AgentConfig(echo_mode=EchoMode.AEC, role=AgentRole.COMMAND)],
    ids=["half-duplex", "command-agent"],
)
def test_no_barge_in_in_half_duplex_or_from_a_command_agent(config: AgentConfig) -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0), spoken_reply("r2", seconds=0.2))
        async with running_agent(config, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.5)
            agent.port.push(playing("someone-elses-stream", 300))
            agent.port.push(VoiceActivity(True))
            await speak(agent.port, 2, seconds=1.0)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert agent.port.of("interruption") == []
        assert "interrupt" not in factory.last.names()
        if config.role is AgentRole.COMMAND:
            assert agent.port.voice() == []  # never audio

    run_virtual(scenario())


def test_the_cut_replies_remembered_are_bounded() -> None:
    """A long session of interruptions must not grow the agent's memory without end."""

    async def scenario() -> None:
        rounds = RECENT_CUTS + 30
        factory = FakeFactory(*(spoken_reply(f"r{n}", seconds=2.0, pace_s=0.2) for n in range(rounds + 1)))
        async with running_agent(DUPLEX, factory) as agent:
            await speak(agent.port, 0, seconds=0.3)
            for n in range(1, rounds + 1):
                await asyncio.sleep(0.5)
                stream = agent.port.streams()[-1]
                agent.port.push(playing(stream, 300))
                agent.port.push(VoiceActivity(True))
                await speak(agent.port, n, seconds=1.0)  # real speech: each reply is cut
            await agent.stop()
        assert agent.runtime.counters.barge_ins > RECENT_CUTS and agent.runtime.counters.false_barge_ins == 0
        assert len(agent.runtime._cut) == RECENT_CUTS  # the newest only

    run_virtual(scenario())
