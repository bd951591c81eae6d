"""Turn-taking from our VAD: streaming, commit on the end marker, text turns, attention, metrics."""

from __future__ import annotations

import asyncio

import pytest
from fake_port import running_agent, silence_pcm, speak
from fake_provider import FakeFactory, spoken_reply
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig
from by_your_command.agents.inputs import Attention, AttentionChanged, CameraFrame, PromptText, UtteranceChunk
from by_your_command.agents.metrics import TurnMetrics

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


def test_voice_turn_streams_resampled_audio_then_commits_and_publishes_one_stream() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=1.0, first_after_s=0.3))
        async with running_agent(AgentConfig(), factory) as agent:
            await speak(agent.port, 7, seconds=0.5, end=False)
            provider = factory.last
            streamed_before_end = len(provider.audio)
            assert "end_of_turn" not in provider.names()
            await speak_end(agent, 7, sequence=5)
            await asyncio.sleep(2.0)
            await agent.stop()
        # streamed as it arrived, not after the end; resampled 16 kHz → 24 kHz (0.6 s of audio)
        assert streamed_before_end > 0
        assert abs(len(provider.audio) - 2 * int(0.6 * 24000)) <= 2
        assert provider.names().index("end_of_turn") > max(
            i for i, n in enumerate(provider.names()) if n == "audio"
        )
        voice = agent.port.voice()
        assert len(agent.port.streams()) == 1
        assert all(chunk.sample_rate == 24000 for chunk in voice)
        assert [chunk.end_of_stream for chunk in voice] == [False] * 5 + [True]
        assert agent.port.of("text") == ["hello there"]
        [turn] = agent.port.turns()
        assert turn.outcome == "completed" and turn.turn_kind == "voice"
        assert turn.stream_id == agent.port.streams()[0]  # monitors tie its playback's end to it
        assert turn.first_audio_ms == pytest.approx(300.0, abs=1.0)  # end marker → first reply audio
        assert turn.usage.output_audio_tokens == 10

    run_virtual(scenario())


async def speak_end(agent, utterance_id: int, sequence: int) -> None:  # type: ignore[no-untyped-def]
    from fake_port import silence_pcm

    agent.port.push(UtteranceChunk(silence_pcm(0.1), 16000, utterance_id, sequence, True))
    await asyncio.sleep(0)


def test_text_turn_gets_a_reply_and_its_transcript() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=0.4))
        async with running_agent(AgentConfig(), factory) as agent:
            agent.port.push(PromptText("  what time is it?  "))
            await asyncio.sleep(1.0)
            await agent.stop()
        assert ("text", "what time is it?") in factory.last.calls
        assert agent.port.of("transcript") == ["what time is it?"]
        assert agent.port.voice()[-1].end_of_stream
        assert [t.turn_kind for t in agent.port.turns()] == ["text"]

    run_virtual(scenario())


def test_nothing_reaches_the_provider_while_asleep_or_muted() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1"))
        async with running_agent(AgentConfig(), factory) as agent:
            for state in (Attention.ASLEEP, Attention.MUTED):
                agent.port.push(AttentionChanged(state))
                await speak(agent.port, int(state == Attention.MUTED) + 1, seconds=0.3)
                agent.port.push(PromptText("hello?"))
                await asyncio.sleep(1.0)
            assert factory.created == []  # not even a session was opened
            agent.port.push(AttentionChanged(Attention.AWAKE))
            await speak(agent.port, 3, seconds=0.3)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert len(factory.created) == 1 and "end_of_turn" in factory.last.names()
        assert agent.runtime.counters.ignored_not_awake == 4

    run_virtual(scenario())


def test_a_lost_end_marker_closes_the_utterance_after_the_idle_deadline() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=0.2))
        async with running_agent(AgentConfig(utterance_idle_s=1.0), factory) as agent:
            await speak(agent.port, 1, seconds=0.3, end=False)
            await asyncio.sleep(3.0)
            await agent.stop()
        assert "end_of_turn" in factory.last.names()
        assert agent.runtime.counters.end_markers_missing == 1
        assert [t.outcome for t in agent.port.turns()] == ["completed"]

    run_virtual(scenario())


def test_camera_frame_goes_with_the_next_turn_and_never_opens_a_session() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=0.2))
        async with running_agent(AgentConfig(), factory) as agent:
            agent.port.push(CameraFrame(b"\xff\xd8jpeg"))
            await asyncio.sleep(5.0)
            assert factory.created == []
            agent.port.push(CameraFrame(b"\xff\xd8jpeg2"))
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            await agent.stop()
        names = factory.last.names()
        # inside the question: after its first audio (Gemini's activity is open), before its end
        assert names.count("image") == 1 and names.index("audio") < names.index("image") < names.index(
            "end_of_turn"
        )

    run_virtual(scenario())


def test_each_question_gets_one_frame_from_its_own_time_never_one_left_from_the_last() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=0.2), spoken_reply("r2", seconds=0.2))
        async with running_agent(AgentConfig(), factory) as agent:
            agent.port.push(CameraFrame(b"\xff\xd8onset-1"))  # forwarded at the first question's onset
            await speak(agent.port, 1, seconds=0.6, end=False)
            agent.port.push(CameraFrame(b"\xff\xd8during-1"))  # the forwarder's later chunk triggers
            await speak_end(agent, 1, sequence=6)
            await asyncio.sleep(1.0)
            # The second question: its first chunk comes before its own onset frame does.
            await speak(agent.port, 2, seconds=0.3, end=False)
            agent.port.push(CameraFrame(b"\xff\xd8onset-2"))
            agent.port.push(CameraFrame(b"\xff\xd8during-2"))
            await speak_end(agent, 2, sequence=3)
            await asyncio.sleep(1.0)
            await agent.stop()
        images = [size for name, size in factory.last.calls if name == "image"]
        assert images == [len(b"\xff\xd8onset-1"), len(b"\xff\xd8onset-2")]

    run_virtual(scenario())


def test_the_frame_forwarded_at_the_onset_beats_an_older_periodic_one() -> None:
    """A periodic frame from 1.9 s before the question must not take its place: the frame
    forwarded at the onset arrives a few ms after the first chunk, and that one is sent."""

    async def scenario() -> None:
        factory = FakeFactory(*(spoken_reply(f"r{n}", seconds=0.2) for n in (1, 2, 3)))
        async with running_agent(AgentConfig(pause_timeout_s=60.0), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)  # a first question opens the session
            await asyncio.sleep(3.0)
            agent.port.push(CameraFrame(b"\xff\xd8periodic"))
            await asyncio.sleep(1.9)
            agent.port.push(UtteranceChunk(silence_pcm(0.1), 16000, 2, 0, False))
            await asyncio.sleep(0.01)
            agent.port.push(CameraFrame(b"\xff\xd8onset"))
            await asyncio.sleep(0.09)
            await speak_end(agent, 2, sequence=1)
            await asyncio.sleep(1.0)
            # the third question: only the old periodic frame, and nothing while it is spoken
            agent.port.push(CameraFrame(b"\xff\xd8periodic-3"))
            await asyncio.sleep(1.9)
            await speak(agent.port, 3, seconds=0.5)
            await asyncio.sleep(1.0)
            await agent.stop()
        calls = factory.last.calls
        images = [size for name, size in calls if name == "image"]
        assert images == [len(b"\xff\xd8onset"), len(b"\xff\xd8periodic-3")]
        ends = [index for index, (name, _) in enumerate(calls) if name == "end_of_turn"]
        last_image = max(index for index, (name, _) in enumerate(calls) if name == "image")
        assert ends[1] < last_image < ends[2]  # still part of the third question

    run_virtual(scenario())


def test_a_second_turn_waits_for_the_reply_in_progress() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=1.0, pace_s=0.2), spoken_reply("r2", seconds=0.2))
        async with running_agent(AgentConfig(), factory) as agent:  # gate: no barge-in
            await speak(agent.port, 1, seconds=0.3)
            await speak(agent.port, 2, seconds=0.2)  # ends while r1 is still being generated
            provider = factory.last
            assert provider.names().count("end_of_turn") == 1
            await asyncio.sleep(3.0)
            await agent.stop()
        assert provider.names().count("end_of_turn") == 2
        turns = agent.port.turns()
        assert [t.outcome for t in turns] == ["completed", "completed"]
        assert isinstance(turns[0], TurnMetrics)

    run_virtual(scenario())


def test_turns_that_wait_together_are_committed_one_by_one_with_their_own_audio() -> None:
    # The provider has one input buffer: two turns streamed while the reply in progress plays would
    # both be taken by the first commit, and the second commit would find it empty.
    async def scenario() -> None:
        factory = FakeFactory(
            spoken_reply("r1", seconds=1.0, pace_s=0.3), spoken_reply("r2", seconds=0.2), spoken_reply("r3")
        )
        async with running_agent(AgentConfig(), factory) as agent:  # gate: no barge-in
            await speak(agent.port, 1, seconds=0.3)
            await speak(agent.port, 2, seconds=0.2)  # both end while r1 is still being generated
            await speak(agent.port, 3, seconds=0.4)
            provider = factory.last
            assert provider.names().count("end_of_turn") == 1
            await asyncio.sleep(5.0)
            await agent.stop()
        committed = [total for name, total in provider.calls if name == "end_of_turn"]
        per_turn = [after - before for before, after in zip([0, *committed], committed, strict=False)]
        bytes_per_s = 24000 * 2  # resampled to the provider's 24 kHz
        assert per_turn == [pytest.approx(s * bytes_per_s, abs=4) for s in (0.3, 0.2, 0.4)]
        assert [t.outcome for t in agent.port.turns()] == ["completed"] * 3

    run_virtual(scenario())
