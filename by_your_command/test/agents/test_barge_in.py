"""Barge-in: the player is paused at the onset; speech that proves real (long enough from the VAD's
onset, with words that are not backchannels) cuts the reply and truncates it at what was heard;
noise and "uh-huh" resume the same stream where it paused. Half duplex and command agents never
pause. A safety stop heard by the VAD cuts the reply. (Through the real VAD and player:
test/agent_process/test_barge_in_graph.py.)"""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from audio_io.synthetic_room import ROBOT_REPLY, Room, at_level, espeak, trim_silence
from fake_port import playing, running_agent, speak
from fake_provider import FakeFactory, spoken_reply, tone
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig, AgentRole, EchoMode
from by_your_command.agents.inputs import PlaybackStatus, SafetyStop, UtteranceChunk, VoiceActivity
from by_your_command.agents.interruptions import RECENT_CUTS
from by_your_command.agents.overlap_words import LocalTranscriber, interrupting_words
from by_your_command.local_speech.speaker import Speaker, SpeakerConfig

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

DUPLEX = AgentConfig(echo_mode=EchoMode.AEC, min_barge_in_ms=400, barge_in_window_s=1.5)
LENGTH_ONLY = AgentConfig(
    echo_mode=EchoMode.AEC, min_barge_in_ms=400, barge_in_window_s=1.5, min_barge_in_words=0
)


class Said:
    """A transcriber that hears the given words (after a virtual decode time)."""

    def __init__(self, text: str, fail: bool = False) -> None:
        self.text = text
        self.fail = fail
        self.calls: list[int] = []

    async def __call__(self, pcm: bytes, sample_rate: int) -> str:
        self.calls.append(len(pcm))
        await asyncio.sleep(0.05)
        if self.fail:
            raise RuntimeError("decoder broke")
        return self.text


async def reply_playing(agent, played_ms: int) -> str:  # type: ignore[no-untyped-def]
    """A first turn whose 2 s reply is generated at once and is now playing at `played_ms`."""
    await speak(agent.port, 1, seconds=0.3)
    await asyncio.sleep(0.5)
    [stream] = agent.port.streams()
    agent.port.push(playing(stream, played_ms))
    await asyncio.sleep(0.001)
    return stream


def test_real_barge_in_pauses_the_player_first_then_cuts_at_what_was_heard() -> None:
    async def scenario() -> None:
        # r1 is generated in real time, so it is still being generated when the user barges in
        factory = FakeFactory(spoken_reply("r1", seconds=2.0, pace_s=0.2), spoken_reply("r2", seconds=0.2))
        async with running_agent(DUPLEX, factory, transcriber=Said("wait a second")) as agent:
            stream = await reply_playing(agent, 700)
            provider = factory.last
            calls_before = len(provider.calls)
            agent.port.push(VoiceActivity(True))
            await asyncio.sleep(0.001)
            # the pause is out before the provider heard anything about it; nothing is cut yet
            assert agent.port.of("pause") == [(stream, "barge_in")]
            assert agent.port.of("interruption") == []
            assert len(provider.calls) == calls_before
            agent.port.push(PlaybackStatus(stream, 760, queued_ms=900, paused=True))  # where it paused
            await speak(agent.port, 2, seconds=1.0)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert agent.port.of("interruption") == [(stream, "barge_in")]
        assert agent.port.of("resume") == []
        names = provider.names()
        interrupt = names.index("interrupt")
        assert provider.calls[interrupt][1] == ("r1", "item-r1", 760)
        # the new utterance's audio follows the interrupt (held while judged, none lost)
        first_new_audio = next(i for i, n in enumerate(names) if n == "audio" and i > interrupt)
        assert first_new_audio > interrupt
        assert names.count("end_of_turn") == 2
        assert len(provider.audio) == 2 * (int(0.3 * 24000) + int(1.0 * 24000))
        assert [t.outcome for t in agent.port.turns()] == ["interrupted", "completed"]
        assert agent.runtime.counters.barge_ins == 1 and agent.runtime.counters.false_barge_ins == 0
        assert agent.runtime.context.history(0)[0].text == "hello there [cut off by the user]"

    run_virtual(scenario())


def test_a_cough_resumes_the_same_stream_where_it_paused() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0, chunk_s=0.2))
        async with running_agent(DUPLEX, factory, transcriber=Said("")) as agent:
            stream = await reply_playing(agent, 500)
            agent.port.push(VoiceActivity(True))
            agent.port.push(PlaybackStatus(stream, 500, queued_ms=1500, paused=True))
            await speak(agent.port, 2, seconds=0.2)  # a cough: shorter than min_barge_in_ms
            await asyncio.sleep(1.0)
            await agent.stop()
        provider = factory.last
        assert "interrupt" not in provider.names()
        assert provider.names().count("end_of_turn") == 1  # the cough was never committed
        assert len(provider.audio) == 2 * int(0.3 * 24000)  # nor sent
        assert agent.port.streams() == [stream]  # no second stream: the player kept the rest
        assert agent.port.of("pause") == [(stream, "barge_in")]
        assert agent.port.of("resume") == [(stream, "false_barge_in")]
        assert agent.port.of("interruption") == []
        assert len(agent.port.stream_audio(stream)) == 2 * 2 * 24000  # the whole reply, once
        assert agent.port.voice()[-1].stream_id == stream and agent.port.voice()[-1].end_of_stream
        assert agent.runtime.counters.false_barge_ins == 1

    run_virtual(scenario())


class SaidSoFar:
    """A transcriber that hears more words as more audio comes: `steps` of (seconds, words)."""

    def __init__(self, *steps: tuple[float, str]) -> None:
        self.steps = steps

    async def __call__(self, pcm: bytes, sample_rate: int) -> str:
        await asyncio.sleep(0.05)
        seconds = len(pcm) / 2 / sample_rate
        return [text for after, text in self.steps if seconds >= after][-1]


def test_speech_judged_false_while_the_user_still_talks_is_judged_again_on_what_follows() -> None:
    """ "Yeah... no wait, go left": the first window holds only a backchannel, so the reply resumes;
    the utterance went on, and its second half must interrupt, not be dropped as noise."""

    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=8.0, chunk_s=0.5), spoken_reply("r2", seconds=0.2))
        transcriber = SaidSoFar((0.0, "yeah"), (2.0, "yeah no wait go left"))
        async with running_agent(DUPLEX, factory, transcriber=transcriber) as agent:
            stream = await reply_playing(agent, 500)
            agent.port.push(VoiceActivity(True))
            agent.port.push(PlaybackStatus(stream, 550, queued_ms=7000, paused=True))
            talking = asyncio.create_task(speak(agent.port, 2, seconds=2.7))  # "yeah ... no wait, go left"
            await asyncio.sleep(1.75)  # the first window: "yeah" only
            assert agent.port.of("resume") == [(stream, "false_barge_in")]
            agent.port.push(playing(stream, 2300))  # it plays on while the user goes on talking
            await talking
            await asyncio.sleep(1.0)
            await agent.stop()
        provider = factory.last
        assert agent.port.of("interruption") == [(stream, "barge_in")]
        interrupt = provider.names().index("interrupt")
        assert provider.calls[interrupt][1][2] >= 2300  # cut where it played, not where it paused
        assert provider.names().count("end_of_turn") == 2  # the utterance is the user's next turn
        assert len(provider.audio) >= 2 * int(2.7 * 24000)  # all of it, "yeah" included

    run_virtual(scenario())


def test_the_vads_pre_roll_is_not_speech() -> None:
    """Issue 34: a cough arrives with half a second of pre-roll; counting all of it confirmed every
    cough on the real graph."""

    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0, chunk_s=0.2))
        async with running_agent(LENGTH_ONLY, factory) as agent:
            stream = await reply_playing(agent, 500)
            agent.port.push(VoiceActivity(True))
            # 0.48 s of pre-roll, 0.1 s of cough, 0.25 s of closing silence (unvoiced too)
            await speak(agent.port, 2, seconds=0.8, unvoiced_s=0.7)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert "interrupt" not in factory.last.names()
        assert agent.port.of("resume") == [(stream, "false_barge_in")]
        assert agent.runtime.counters.false_barge_ins == 1

    run_virtual(scenario())


@pytest.mark.parametrize("said", ["uh huh", "yeah okay", "mm-hm right"])
def test_a_backchannel_long_enough_to_be_speech_resumes_the_reply(said: str) -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=3.0, chunk_s=0.2))
        async with running_agent(DUPLEX, factory, transcriber=Said(said)) as agent:
            stream = await reply_playing(agent, 500)
            agent.port.push(VoiceActivity(True))
            await speak(agent.port, 2, seconds=0.7)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert "interrupt" not in factory.last.names()
        assert agent.port.of("resume") == [(stream, "false_barge_in")]
        assert agent.runtime.counters.false_barge_ins == 1

    run_virtual(scenario())


@pytest.mark.parametrize(("said", "seconds", "cut"), [("wait um oh", 1.2, True), ("little", 0.6, False)])
def test_long_speech_with_one_word_that_is_not_a_backchannel_interrupts(
    said: str, seconds: float, cut: bool
) -> None:
    """Over the robot's voice the recogniser merged "wait a moment" into "wait um oh": one word
    that counts, but 1.2 s of speech is no backchannel. A 0.6 s "uh-huh" heard "little" is."""

    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=4.0, chunk_s=0.2), spoken_reply("r2", seconds=0.2))
        async with running_agent(DUPLEX, factory, transcriber=Said(said)) as agent:
            stream = await reply_playing(agent, 500)
            agent.port.push(VoiceActivity(True))
            await speak(agent.port, 2, seconds=seconds)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert agent.port.of("interruption") == ([(stream, "barge_in")] if cut else [])
        assert agent.port.of("resume") == ([] if cut else [(stream, "false_barge_in")])

    run_virtual(scenario())


def test_a_false_then_a_real_barge_in_truncates_at_all_that_was_heard() -> None:
    """Issue 34: the resumed remainder was a new stream whose played_ms started at 0, so the later
    truncation point was what was heard since the resume, not of the whole reply."""

    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=10.0, chunk_s=0.5), spoken_reply("r2", seconds=0.2))
        transcriber = Said("")
        async with running_agent(DUPLEX, factory, transcriber=transcriber) as agent:
            stream = await reply_playing(agent, 4000)
            agent.port.push(VoiceActivity(True))
            agent.port.push(PlaybackStatus(stream, 4000, queued_ms=6000, paused=True))
            await speak(agent.port, 2, seconds=0.2)  # a cough
            await asyncio.sleep(0.5)
            assert agent.port.of("resume") == [(stream, "false_barge_in")]
            agent.port.push(playing(stream, 7000))  # three seconds more were heard
            await asyncio.sleep(0.001)
            transcriber.text = "no tell me about the kitchen"
            agent.port.push(VoiceActivity(True))
            agent.port.push(PlaybackStatus(stream, 7020, queued_ms=2980, paused=True))
            await speak(agent.port, 3, seconds=1.0)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert agent.port.of("pause") == [(stream, "barge_in")] * 2
        assert agent.port.of("interruption") == [(stream, "barge_in")]
        assert ("interrupt", ("r1", "item-r1", 7020)) in factory.last.calls

    run_virtual(scenario())


def test_the_truncation_point_before_the_players_pause_report_is_estimated_and_clamped() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0, pace_s=0.1), spoken_reply("r2", seconds=0.2))
        async with running_agent(LENGTH_ONLY, factory) as agent:
            stream = await reply_playing(agent, 300)
            await asyncio.sleep(0.2)  # the player said 300 ms, 0.2 s ago, and played on
            agent.port.push(VoiceActivity(True))
            await speak(agent.port, 2, seconds=1.0)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert agent.port.of("interruption") == [(stream, "barge_in")]
        [(_, (_, _, heard))] = [c for c in factory.last.calls if c[0] == "interrupt"]
        assert heard == pytest.approx(500, abs=2)

    run_virtual(scenario())


def test_a_failing_transcriber_leaves_the_verdict_to_the_speechs_length() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0, pace_s=0.2), spoken_reply("r2", seconds=0.2))
        transcriber = Said("", fail=True)
        async with running_agent(DUPLEX, factory, transcriber=transcriber) as agent:
            stream = await reply_playing(agent, 300)
            agent.port.push(VoiceActivity(True))
            await speak(agent.port, 2, seconds=1.0)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert transcriber.calls
        assert agent.port.of("interruption") == [(stream, "barge_in")]
        assert agent.runtime.counters.internal_errors >= 1

    run_virtual(scenario())


def test_an_onset_without_speech_is_false_after_the_window() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0))
        async with running_agent(DUPLEX, factory) as agent:
            stream = await reply_playing(agent, 300)
            agent.port.push(VoiceActivity(True))  # a VAD blip: no utterance follows
            await asyncio.sleep(2.0)
            await agent.stop()
        assert agent.port.of("pause") == [(stream, "barge_in")]
        assert agent.port.of("resume") == [(stream, "false_barge_in")]
        assert agent.port.streams() == [stream]
        assert agent.runtime.counters.false_barge_ins == 1

    run_virtual(scenario())


def test_barge_in_works_after_generation_ended_from_playback_status() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0), spoken_reply("r2", seconds=0.2))
        async with running_agent(LENGTH_ONLY, factory) as agent:
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


def test_a_safety_stop_cuts_the_reply_and_the_model_learns_it() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=3.0, pace_s=0.2))
        async with running_agent(AgentConfig(), factory) as agent:  # half duplex: no barge-in
            stream = await reply_playing(agent, 400)
            agent.port.push(SafetyStop("stop"))
            await asyncio.sleep(1.0)
            published = len(agent.port.stream_audio(stream))
            await asyncio.sleep(2.0)
            await agent.stop()
        assert agent.port.of("interruption") == [(stream, "safety_stop")]
        assert len(agent.port.stream_audio(stream)) == published  # nothing more of it
        [(_, (response, _, heard))] = [c for c in factory.last.calls if c[0] == "interrupt"]
        assert response == "r1" and heard == pytest.approx(400, abs=2)  # played on since its report
        assert agent.runtime.counters.safety_stops == 1
        assert [t.outcome for t in agent.port.turns()] == ["interrupted"]
        texts = [turn.text for turn in agent.runtime.context.history(0)]
        assert any('"stop" (the robot heard this itself' in text for text in texts)
        # the live session is told too, without being asked for a reply
        [(_, note)] = [call for call in factory.last.calls if call[0] == "context"]
        assert note.startswith('"stop" (the robot heard this itself')
        assert factory.last.names().count("end_of_turn") == 1

    run_virtual(scenario())


@pytest.mark.parametrize("stop_first", [False, True], ids=["during-the-utterance", "before-its-chunks"])
def test_the_utterance_that_carried_a_safety_stop_is_not_a_request(stop_first: bool) -> None:
    """The robot silent, the user says "stop": the VAD's spotter routed it, and the same utterance
    on prompt_voice would make the model route it again and answer. The stop names it: dropped."""

    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=0.5), spoken_reply("r2", seconds=0.5))
        async with running_agent(AgentConfig(), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)  # a first exchange: the session is open
            await asyncio.sleep(1.0)
            if stop_first:  # two topics, no order: the stop may come before the utterance
                agent.port.push(SafetyStop("stop", utterance_id=2))
                await speak(agent.port, 2, seconds=0.4)
            else:
                talking = asyncio.create_task(speak(agent.port, 2, seconds=0.4))
                await asyncio.sleep(0.25)
                agent.port.push(SafetyStop("stop", utterance_id=2))
                await talking
            await asyncio.sleep(2.0)
            await agent.stop()
        names = [name for provider in factory.created for name in provider.names()]
        assert names.count("end_of_turn") == 1  # only the first exchange was a request
        assert [t.turn for t in agent.port.turns()] == [1]
        if not stop_first:  # its first audio was streamed: that session is not used again
            assert factory.created[0].closed

    run_virtual(scenario())


@pytest.mark.parametrize("reply_began", [False, True], ids=["before-its-reply", "while-it-plays"])
def test_a_stop_that_was_already_committed_gets_no_reply(reply_began: bool) -> None:
    """The VAD's end marker usually comes before the spotter's verdict (two topics): the model was
    already asked. What it answers to "stop" is neither said nor acted on; its session closes and
    the next question goes to a new one that has the stop as a note."""

    async def scenario() -> None:
        factory = FakeFactory(
            spoken_reply("r1", seconds=0.5),
            spoken_reply("r2", seconds=2.0, text="okay, stopping", first_after_s=0.3, pace_s=0.2),
            spoken_reply("r3", seconds=0.5, text="it is noon"),
        )
        async with running_agent(AgentConfig(), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)  # a first exchange: the session is open
            await asyncio.sleep(1.0)
            await speak(agent.port, 2, seconds=0.4)  # "stop": committed at its end marker
            await asyncio.sleep(0.5 if reply_began else 0.1)
            agent.port.push(SafetyStop("stop", utterance_id=2))
            await asyncio.sleep(3.0)
            await speak(agent.port, 3, seconds=0.4)  # the next question
            await asyncio.sleep(2.0)
            await agent.stop()
        assert len(factory.created) == 2  # the stop's session closed; the next question opened another
        assert agent.port.of("text") == ["hello there", "it is noon"]  # nothing of "okay, stopping"
        streams = agent.port.streams()
        if reply_began:  # what was already playing is cut at once, nothing more of it comes
            assert len(streams) == 3
            assert agent.port.of("interruption") == [(streams[1], "safety_stop")]
            assert len(agent.port.stream_audio(streams[1])) < len(tone(2.0))
        else:
            assert len(streams) == 2
        assert [(t.turn, t.outcome) for t in agent.port.turns()] == [
            (1, "completed"),
            (2, "stopped"),
            (3, "completed"),
        ]
        history = [turn.text for turn in factory.created[1].setup.history]
        assert any('"stop" (the robot heard this itself' in text for text in history)
        assert factory.created[1].names().count("end_of_turn") == 1

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
        assert agent.port.of("interruption") == [] and agent.port.of("pause") == []
        assert "interrupt" not in factory.last.names()
        if config.role is AgentRole.COMMAND:
            assert agent.port.voice() == []  # never audio

    run_virtual(scenario())


def test_the_cut_replies_remembered_are_bounded() -> None:
    """A long session of interruptions must not grow the agent's memory without end."""

    async def scenario() -> None:
        rounds = RECENT_CUTS + 30
        factory = FakeFactory(*(spoken_reply(f"r{n}", seconds=2.0, pace_s=0.2) for n in range(rounds + 1)))
        async with running_agent(LENGTH_ONLY, factory) as agent:
            await speak(agent.port, 0, seconds=0.3)
            for n in range(1, rounds + 1):
                await asyncio.sleep(0.5)
                stream = agent.port.streams()[-1]
                agent.port.push(playing(stream, 300))
                agent.port.push(VoiceActivity(True))
                await speak(agent.port, n, seconds=1.0)  # real speech: each reply is cut
            await agent.stop()
        assert agent.runtime.counters.barge_ins > RECENT_CUTS and agent.runtime.counters.false_barge_ins == 0
        assert len(agent.runtime._interruptions.cut) == RECENT_CUTS  # the newest only

    run_virtual(scenario())


@pytest.mark.parametrize(
    ("text", "left"),
    [
        ("uh-huh", []),
        ("uh huh yeah", []),
        ("okay i see", []),
        ("wait a second", ["wait", "a", "second"]),
        ("yeah but no", ["but", "no"]),
        ("", []),
    ],
)
def test_backchannel_phrases_are_taken_out_of_what_was_heard(text: str, left: list[str]) -> None:
    assert interrupting_words(text, DUPLEX.backchannels) == left


def test_the_local_transcriber_hears_words_in_speech_and_few_in_a_backchannel() -> None:
    """The real recogniser (pocketsphinx, small vocabulary) on espeak-ng speech: a sentence brings
    enough interrupting words, "okay" and "uh huh" not (bench_barge_in.py measures many voices)."""
    speaker = Speaker(SpeakerConfig(voice="en-us", sample_rate=16000))
    transcribe = LocalTranscriber(DUPLEX.backchannels)

    def words(text: str) -> list[str]:
        pcm, rate = speaker.say(text)
        return interrupting_words(transcribe(pcm, rate), DUPLEX.backchannels)

    assert len(words("what about the dogs")) >= DUPLEX.min_barge_in_words
    assert len(words("okay")) < DUPLEX.min_barge_in_words
    assert len(words("uh huh")) < DUPLEX.min_barge_in_words


@pytest.mark.parametrize(
    ("said", "voice", "echo_at_s", "echo_dbfs"),
    [("uh huh", "en-us", 2.0, -44.0), ("yeah", "en-us", 2.0, -38.0), ("yeah", "en-us+f3", 1.0, -44.0)],
)
def test_the_robots_echo_in_the_pre_roll_lends_a_backchannel_no_words(
    said: str, voice: str, echo_at_s: float, echo_dbfs: float
) -> None:
    """The real recogniser on a backchannel whose 480 ms of pre-roll hold the robot's residual
    echo (12-18 dB under the user): decoded with all of it, the echo lent these backchannels words
    and the reply was cut; heard from just before the onset, it resumes."""
    rate = 16000
    echo = at_level(
        Room().echo(at_level(trim_silence(espeak(ROBOT_REPLY, "en-gb", rate), rate), -18.0), rate), echo_dbfs
    )
    user = at_level(trim_silence(espeak(said, voice, rate), rate), -26.0)
    pre_roll, tail = int(0.48 * rate), int(0.25 * rate)
    start = int(echo_at_s * rate)
    mic = echo[start : start + pre_roll + len(user) + tail].astype(np.float64)
    mic[pre_roll : pre_roll + len(user)] += user
    pcm = np.clip(mic, -32768, 32767).astype("<i2")
    local = LocalTranscriber(DUPLEX.backchannels)

    async def transcribe(audio: bytes, sample_rate: int) -> str:
        return local(audio, sample_rate)

    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=4.0, chunk_s=0.2), spoken_reply("r2", seconds=0.2))
        async with running_agent(DUPLEX, factory, transcriber=transcribe) as agent:
            stream = await reply_playing(agent, 500)
            agent.port.push(VoiceActivity(True))
            chunk = rate // 10
            for sequence, k in enumerate(range(0, len(pcm), chunk)):
                last = k + chunk >= len(pcm)
                unvoiced = min(k + chunk, pre_roll) + (tail if last else 0)  # as the VAD counts
                agent.port.push(
                    UtteranceChunk(pcm[k : k + chunk].tobytes(), rate, 2, sequence, last, unvoiced)
                )
                await asyncio.sleep(0.1)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert agent.port.of("interruption") == []
        assert agent.port.of("resume") == [(stream, "false_barge_in")]

    run_virtual(scenario())
