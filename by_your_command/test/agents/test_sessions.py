"""Session cycling for cost, rotation, and robustness: deadlines, reconnects, undeliverable turns,
fatal errors, rate limits. All on virtual time against the scripted provider."""

from __future__ import annotations

import asyncio

import pytest
from fake_port import FakePort, playing, running_agent, speak
from fake_provider import FakeFactory, FakeProvider, spoken_reply
from virtual_time import VirtualClock, run_virtual

from by_your_command.agents.config import AgentConfig, EchoMode
from by_your_command.agents.events import ProviderError, SessionEnding, Usage, UserTranscript
from by_your_command.agents.inputs import (
    ConversationReset,
    InputLost,
    PlaybackStatus,
    PromptText,
    SharedTurn,
    VoiceActivity,
)
from by_your_command.agents.metrics import SessionOpenedMetrics
from by_your_command.agents.port import VoiceChunk
from by_your_command.agents.provider import ProviderFailure, Role
from by_your_command.agents.runtime import AgentFatal, AgentRuntime

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


def test_pause_closes_the_session_and_speech_reopens_it_with_history_and_no_lost_audio() -> None:
    async def scenario() -> None:
        def slow_second_connect(provider: FakeProvider, index: int) -> None:
            provider.connect_delay_s = 0.8 if index == 1 else 0.0

        usage = Usage(input_audio_tokens=40, output_audio_tokens=60)
        factory = FakeFactory(
            spoken_reply("r1", seconds=0.4, usage=usage),
            spoken_reply("r2", 0.2),
            configure=slow_second_connect,
        )
        async with running_agent(AgentConfig(pause_timeout_s=10.0), factory) as agent:
            await speak(agent.port, 1, seconds=0.5)
            factory.last.emit(UserTranscript("what is your name", usage=Usage(input_text_tokens=5)))
            await asyncio.sleep(9.0)
            assert not factory.created[0].closed  # not yet: the pause is counted from the last activity
            await asyncio.sleep(3.0)
            assert factory.created[0].closed
            [closed] = agent.port.sessions()
            assert closed.close_reason.startswith("pause")
            assert closed.usage == usage + Usage(input_text_tokens=5)
            assert 10.0 <= closed.billed_s <= 11.0
            # speech onset reopens; the slow connect hides behind the utterance and loses nothing
            agent.port.push(VoiceActivity(True))
            await speak(agent.port, 2, seconds=0.6)
            await asyncio.sleep(2.0)
            await agent.stop()
        second = factory.created[1]
        assert len(second.audio) == 2 * int(0.6 * 24000)
        assert second.setup is not None
        assert [(h.role, h.text) for h in second.setup.history] == [
            (Role.USER, "what is your name"),
            (Role.ASSISTANT, "hello there"),
        ]
        assert len(factory.created) == 2

    run_virtual(scenario())


def test_the_agents_own_and_state_messages_never_open_a_paid_session() -> None:
    async def scenario() -> None:
        factory = FakeFactory()
        async with running_agent(AgentConfig(conversation_timeout_s=30.0), factory) as agent:
            agent.port.push(ConversationReset("conv-x"))
            agent.port.push(SharedTurn(Role.ASSISTANT, "hi"))
            agent.port.push(PlaybackStatus("x", 10, speaking=True))
            agent.port.push(VoiceActivity(False))
            agent.port.push(InputLost("prompt_voice", None, "connection to the bridge lost"))
            await asyncio.sleep(120.0)  # conversation timeouts pass too
            await agent.stop()
        assert factory.created == []
        assert agent.runtime.counters.inputs_lost == 1

    run_virtual(scenario())


def test_rotation_before_the_provider_limit_happens_at_a_turn_boundary() -> None:
    async def scenario() -> None:
        def short_limit(provider: FakeProvider, index: int) -> None:
            provider.max_session_s = 60.0

        factory = FakeFactory(*[spoken_reply(f"r{i}", 0.2) for i in range(4)], configure=short_limit)
        config = AgentConfig(rotation_margin_s=10.0, pause_timeout_s=100.0)
        async with running_agent(config, factory) as agent:
            for utterance in range(3):
                await speak(agent.port, utterance + 1, seconds=0.3)
                await asyncio.sleep(29.0)
            await asyncio.sleep(1.0)
            await agent.stop()
        first = factory.created[0]
        assert first.closed and first.names().count("end_of_turn") == 2
        reasons = [s.close_reason for s in agent.port.sessions()]
        assert reasons[0] == "rotation before the limit"
        assert len(factory.created) == 2

    run_virtual(scenario())


def test_a_due_rotation_happens_before_the_next_turn_even_with_no_idle_moment_between_turns() -> None:
    """The next question arrives before the player says the last reply ended (two topics: no order
    between them): the session is never idle, and it must not reach the provider's limit."""

    async def scenario() -> None:
        def short_limit(provider: FakeProvider, index: int) -> None:
            provider.max_session_s = 10.0

        factory = FakeFactory(*[spoken_reply(f"r{i}", 1.0) for i in range(12)], configure=short_limit)
        config = AgentConfig(rotation_margin_s=5.0, pause_timeout_s=100.0)
        async with running_agent(config, factory) as agent:
            for question in range(12):
                agent.port.push(PromptText(f"question {question}"))
                await asyncio.sleep(1.0)  # answered; it plays until the next question comes
                for stream in agent.port.streams():
                    agent.port.push(playing(stream, 900))
            await asyncio.sleep(1.0)
            await agent.stop()
        opened = [provider.names().count("text") for provider in factory.created]
        assert sum(opened) == 12 and len(factory.created) >= 2
        reasons = [s.close_reason for s in agent.port.sessions()]
        assert reasons[0] == "rotation before the limit"
        assert [t.outcome for t in agent.port.turns()] == ["completed"] * 12

    run_virtual(scenario())


def test_a_provider_that_never_answers_fails_the_turn_reports_it_and_recycles_the_session() -> None:
    async def scenario() -> None:
        def mute_first(provider: FakeProvider, index: int) -> None:
            provider.replying = index > 0

        factory = FakeFactory(spoken_reply("r1", 0.2), configure=mute_first)
        config = AgentConfig(reply_timeout_s=5.0, connect_attempts=2)
        async with running_agent(config, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(4.0)
            assert not factory.created[0].closed
            await asyncio.sleep(30.0)
            await agent.stop()
        # first session recycled; the turn, never answered, was replayed whole on a second session
        assert factory.created[0].closed
        assert len(factory.created[1].audio) == 2 * int(0.3 * 24000)
        assert [t.outcome for t in agent.port.turns()] == ["completed"]

    run_virtual(scenario())


def test_a_turn_that_cannot_be_delivered_is_reported_and_counted() -> None:
    async def scenario() -> None:
        def refuse(provider: FakeProvider, index: int) -> None:
            provider.connect_error = OSError("network unreachable")

        factory = FakeFactory(configure=refuse)
        config = AgentConfig(connect_attempts=3, backoff_initial_s=0.5)
        async with running_agent(config, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(30.0)
            await agent.stop()
        assert len(factory.created) == 3
        [report] = agent.port.turns()
        assert report.outcome == "undelivered" and "network unreachable" in report.reason
        assert agent.port.of("text") == []  # a report is not the robot's speech
        assert agent.runtime.counters.utterances_undeliverable == 1
        assert agent.runtime.counters.connect_failures == 3

    run_virtual(scenario())


def test_a_reply_cut_by_a_dropped_session_is_failed_and_reported() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0, pace_s=0.2), spoken_reply("r2", 0.2))
        async with running_agent(AgentConfig(), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.5)
            factory.last.drop()
            await asyncio.sleep(1.0)
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert [t.outcome for t in agent.port.turns()] == ["failed", "completed"]
        assert "the provider closed the session" in agent.port.turns()[0].reason
        assert agent.port.of("text") == ["hello there"]  # the second reply's words, and no report
        assert agent.runtime.counters.turns_failed == 1

    run_virtual(scenario())


def test_a_provider_closing_after_its_go_away_while_the_reply_plays_is_the_announced_end() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=3.0), spoken_reply("r2", 0.2))
        async with running_agent(AgentConfig(pause_timeout_s=100.0), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(0.5)  # the whole reply is received; it plays for 3 s
            factory.last.emit(SessionEnding("goAway", 0.5))
            await asyncio.sleep(0.5)
            factory.last.drop()  # the server closes before our turn boundary (the reply still plays)
            await asyncio.sleep(4.0)
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert [t.outcome for t in agent.port.turns()] == ["completed", "completed"]
        reasons = [s.close_reason for s in agent.port.sessions()]
        assert reasons == ["the provider is ending the session (goAway)", "agent stopped"]
        opened = [r.session for r in agent.port.of("metrics") if isinstance(r, SessionOpenedMetrics)]
        assert opened == [1, 2]  # each session announced when it opened, before its turns
        assert agent.runtime.counters.sessions_failed == 0
        assert not any("failed" in text for text in agent.port.of("text"))

    run_virtual(scenario())


def test_an_auth_error_stops_the_agent_with_one_clear_message() -> None:
    async def scenario() -> None:
        def bad_key(provider: FakeProvider, index: int) -> None:
            provider.connect_error = ProviderFailure(
                ProviderError("invalid_api_key", "Incorrect API key provided", fatal=True)
            )

        factory = FakeFactory(configure=bad_key)
        async with running_agent(AgentConfig(), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            with pytest.raises(AgentFatal, match="invalid_api_key: Incorrect API key provided"):
                await asyncio.wait_for(agent.task, 10)
        assert len(factory.created) == 1

    run_virtual(scenario())


def test_a_rate_limit_delays_the_next_connect() -> None:
    async def scenario() -> None:
        def limited(provider: FakeProvider, index: int) -> None:
            if index == 0:
                provider.connect_error = ProviderFailure(
                    ProviderError("rate_limit_exceeded", "slow down", retry_after_s=20.0)
                )

        factory = FakeFactory(spoken_reply("r1", 0.2), configure=limited)
        async with running_agent(AgentConfig(), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(10.0)
            assert len(factory.created) == 1  # waiting out the limit
            await asyncio.sleep(15.0)
            await agent.stop()
        assert [t.outcome for t in agent.port.turns()] == ["completed"]

    run_virtual(scenario())


def test_publishing_while_the_bridge_is_down_is_counted_not_fatal() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", 0.4), spoken_reply("r2", 0.2))
        async with running_agent(AgentConfig(), factory) as agent:
            agent.port.unavailable = True
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            agent.port.unavailable = False
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(1.0)
            await agent.stop()
        # turn 1 while down: session opened, two audio chunks and the stream's end, the words, the turn
        assert agent.runtime.counters.publish_failures == 6
        assert [t.turn for t in agent.port.turns()] == [2]
        assert agent.port.of("text") == ["hello there"]

    run_virtual(scenario())


def test_a_slow_bridge_never_delays_an_interruption_and_the_cut_audio_is_not_sent() -> None:
    class SlowVoicePort(FakePort):
        async def publish_voice(self, chunk: VoiceChunk) -> None:
            await asyncio.sleep(1.5)  # each chunk takes 1.5 s to go out (under the publish timeout)
            await super().publish_voice(chunk)

    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0))  # ten chunks, all at once
        port = SlowVoicePort()
        config = AgentConfig(echo_mode=EchoMode.AEC)  # the user may cut in
        runtime = AgentRuntime(config, "You are a test robot.", port, factory, VirtualClock())
        task = asyncio.create_task(runtime.run())
        await speak(port, 1, seconds=0.3)
        await asyncio.sleep(0.5)
        onset = asyncio.get_running_loop().time()
        port.push(VoiceActivity(True))
        await speak(port, 2, seconds=1.0)  # real speech: the reply is cut
        cut_at = asyncio.get_running_loop().time()
        await asyncio.sleep(10.0)
        port.close()
        await asyncio.wait_for(task, 30)
        [(paused_at, _, (stream, reason))] = [entry for entry in port.published if entry[1] == "pause"]
        assert paused_at == onset and reason == "barge_in"  # not after the audio queued before it
        [(at, _, (cut, _))] = [entry for entry in port.published if entry[1] == "interruption"]
        assert cut == stream and at < cut_at
        sent = [chunk for chunk in port.voice() if chunk.stream_id == stream]
        assert 0 < len(sent) < 10  # what was still queued when the reply was cut never went out

    run_virtual(scenario())


def test_a_provider_close_that_ignores_its_cancellation_does_not_hold_the_agent() -> None:
    """A library's close handshake that goes on after its timeout (it swallows the cancellation):
    the session is closed within close_timeout_s all the same, and the next question is answered
    at once, not after the library is done."""

    async def scenario() -> None:
        def stubborn_first_close(provider: FakeProvider, index: int) -> None:
            if index > 0:
                return
            plain_close = provider.close

            async def close() -> None:
                await plain_close()
                try:
                    await asyncio.sleep(60.0)
                except asyncio.CancelledError:
                    await asyncio.sleep(60.0)  # finishes its handshake regardless

            provider.close = close  # type: ignore[method-assign]

        factory = FakeFactory(
            spoken_reply("r1", 0.2), spoken_reply("r2", 0.2), configure=stubborn_first_close
        )
        config = AgentConfig(pause_timeout_s=2.0, close_timeout_s=3.0)
        async with running_agent(config, factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(6.0)  # the pause closed it (its close hangs in the library)
            loop = asyncio.get_running_loop()
            asked_at = loop.time()
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(3.0)
            answered = [at for at, kind, _ in agent.port.published if kind == "text"]
            await agent.stop()
        assert len(answered) == 2 and answered[1] - asked_at < 2.0
        assert [s.close_reason for s in agent.port.sessions()][0].startswith("pause")

    run_virtual(scenario())
