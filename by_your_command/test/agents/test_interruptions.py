"""Interruptions on its own (agents/interruptions.py): the reply paused at the user's speech, resumed
or cut on the verdict, the held speech released, the transcription of it, and the cuts of a safety
stop and of a model that yielded — without a runtime, a provider or an event loop of its own. (The
judge itself: test_barge_in_watch.py; the same flow through the whole runtime: test_barge_in.py,
test_duplex.py; through the real VAD and player: test/agent_process/test_barge_in_graph.py.) At the
end, the runtime's side of the seam where test_barge_in.py leaves it open: a verdict that comes
after the utterance or the reply ended."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any

import pytest
from fake_port import FakePort, playing, running_agent, speak
from fake_provider import FakeFactory, spoken_reply
from test_robot_runner import FakeSession
from virtual_time import run_virtual

from by_your_command.agents.config import AgentConfig, EchoMode
from by_your_command.agents.inputs import VoiceActivity
from by_your_command.agents.interruptions import RECENT_CUTS, TRANSCRIBED_PRE_ROLL_MS, Interruptions
from by_your_command.agents.metrics import Counters
from by_your_command.agents.reply_audio import ReplyAudio
from by_your_command.agents.session import Interrupt, SendAudio
from by_your_command.agents.turn import Turn
from by_your_command.audio.pcm import StreamResampler

pytestmark = pytest.mark.unit

LENGTH_DECIDES = AgentConfig(echo_mode=EchoMode.AEC, min_barge_in_words=0, barge_in_window_s=1.5)
WORDS_DECIDE = AgentConfig(echo_mode=EchoMode.AEC, min_barge_in_words=2, barge_in_window_s=1.5)
RATE = 24000  # the provider's input rate (the held audio's)


@dataclass
class Transcriber:
    """Says `text` (or raises `error`) of whatever it is given, after `decode_s` of (virtual) time;
    records what it was given."""

    text: str = ""
    error: Exception | None = None
    decode_s: float = 0.0
    given: list[tuple[int, int]] = field(default_factory=list)  # (bytes, rate)

    async def __call__(self, pcm: bytes, rate: int) -> str:
        self.given.append((len(pcm), rate))
        if self.decode_s:
            await asyncio.sleep(self.decode_s)
        if self.error is not None:
            raise self.error
        return self.text


@dataclass
class Host:
    """What the runtime hands Interruptions, recorded."""

    config: AgentConfig = LENGTH_DECIDES
    transcriber: Transcriber | None = None
    port: FakePort = field(default_factory=FakePort)
    counters: Counters = field(default_factory=Counters)
    session: FakeSession | None = field(default_factory=lambda: FakeSession(1))
    sends: list[tuple[str, Callable[[], Awaitable[None]]]] = field(default_factory=list)
    discarded: list[str] = field(default_factory=list)

    def interruptions(self) -> Interruptions:
        return Interruptions(
            self.config,
            self.counters,
            self.port,
            self.transcriber,
            publish=lambda what, send: self.sends.append((what, send)),
            wall=lambda: 1.7e9,
            discard_stream=self.discarded.append,
            session=lambda: self.session,  # type: ignore[arg-type,return-value]
        )

    def player(self) -> list[tuple[str, str, str]]:
        """What the player was told since last asked, in order: (action, stream, reason) (the outbox's
        job in the runtime)."""
        sends, self.sends = self.sends, []
        assert {what for what, _ in sends} <= {"interruption_signal"}
        self.port.published.clear()
        asyncio.run(_in_order([send for _, send in sends]))
        return [(kind, *payload) for _, kind, payload in self.port.published]

    def sent(self) -> list[Any]:
        assert self.session is not None
        return self.session.sent


async def _in_order(sends: list[Callable[[], Awaitable[None]]]) -> None:
    for send in sends:
        await send()


def reply(session: int = 1) -> ReplyAudio:
    """Three seconds of reply, published from t=100 s on (audible until 105 s, with the grace)."""
    audio = ReplyAudio("r1", "item-r1", RATE, "talker-1", session, 1)
    audio.received_bytes = 3 * audio.bytes_per_s
    audio.stream_started_at = 100.0
    return audio


def speech(ms: float, ended: bool = False) -> Turn:
    """The user's utterance so far: `ms` of speech at the provider's rate."""
    turn = Turn(2, "voice", 100.5, 1 << 22, utterance_id=2)
    turn.resampler = StreamResampler(16000, RATE)
    more(turn, ms)
    if ended:
        turn.ended_at = 101.0
    return turn


def more(turn: Turn, ms: float) -> None:
    turn.received_ms += ms
    turn.audio += bytes(2 * RATE * int(ms) // 1000)


def paused(host: Host, turn: Turn, at: float = 100.5) -> tuple[Interruptions, ReplyAudio]:
    """The reply paused by speech at `at`, the utterance `turn` joined (held)."""
    interruptions = host.interruptions()
    audio = reply()
    interruptions.speech_onset(audio, at)
    interruptions.join(turn)
    return interruptions, audio


def test_speech_over_an_audible_reply_pauses_it_and_holds_the_utterance_that_follows() -> None:
    host = Host()
    interruptions = host.interruptions()
    audio = reply()
    interruptions.speech_onset(audio, 100.5)
    assert host.player() == [("pause", "talker-1", "barge_in")]
    assert host.counters.barge_ins == 1
    assert interruptions.pending and interruptions.judging(audio) and not interruptions.judging(reply())
    assert interruptions.deadline() == 100.5 + 1.5
    turn = speech(100)
    interruptions.join(turn)
    assert turn.held and interruptions.judges(turn) and interruptions.utterance is turn
    later = speech(100)
    interruptions.join(later)  # one utterance is judged: the next is an ordinary one
    assert not later.held and not interruptions.judges(later)
    interruptions.speech_onset(audio, 100.7)  # already paused
    assert host.player() == [] and host.counters.barge_ins == 1


def test_speech_pauses_nothing_without_barge_in_or_an_audible_reply_not_cut() -> None:
    half_duplex = Host(config=AgentConfig(echo_mode=EchoMode.GATE))
    half_duplex.interruptions().speech_onset(reply(), 100.5)
    host = Host()
    interruptions = host.interruptions()
    interruptions.speech_onset(None, 100.5)
    interruptions.speech_onset(reply(), 105.5)  # played out
    cut = reply()
    cut.cut = True
    interruptions.speech_onset(cut, 100.5)
    for nothing in (half_duplex, host):
        assert nothing.player() == [] and nothing.counters.barge_ins == 0
    assert not interruptions.pending and interruptions.deadline() is None
    interruptions.join(turn := speech(100))
    assert not turn.held


def test_undecided_speech_waits_and_changes_nothing() -> None:
    host = Host()
    interruptions, audio = paused(host, turn := speech(200))
    host.player()
    assert interruptions.judge(101.0, turn) is None
    assert interruptions.pending and turn.held and host.player() == [] and host.sent() == []
    assert not audio.cut


def test_confirmed_speech_cuts_the_reply_where_it_paused_and_the_model_hears_the_held_audio() -> None:
    host = Host()
    turn = speech(500)
    interruptions, audio = paused(host, turn)
    host.player()
    assert interruptions.judge(101.2, turn) is audio
    assert host.player() == [("interruption", "talker-1", "barge_in")]
    assert host.discarded == ["talker-1"]  # what was still queued for the player goes too
    # heard: from its first chunk (100 s) to the pause (100.5 s), not to the verdict
    assert host.sent() == [Interrupt("r1", "item-r1", 500), SendAudio(bytes(turn.audio))]
    assert audio.cut and interruptions.was_cut("r1") and not interruptions.was_cut("r2")
    assert not turn.held and not interruptions.pending and interruptions.deadline() is None
    assert host.counters.false_barge_ins == 0


def test_a_cut_reaches_the_model_only_in_the_session_that_made_the_reply() -> None:
    host = Host(session=FakeSession(2))  # the reply is session 1's
    turn = speech(500)
    interruptions, audio = paused(host, turn)
    interruptions.judge(101.0, turn)
    assert host.sent() == [SendAudio(bytes(turn.audio))]
    assert [action for action, _, _ in host.player()] == ["pause", "interruption"]
    no_session = Host(session=None)
    interruptions, audio = paused(no_session, speech(500))
    interruptions.judge(101.0, None)
    assert audio.cut and [a for a, _, _ in no_session.player()] == ["pause", "interruption"]


def test_held_audio_of_a_turn_waiting_for_its_commit_is_released_but_not_sent_now() -> None:
    host = Host()
    turn = speech(500)
    turn.deferred = True  # it goes at its commit (one input buffer)
    interruptions, _ = paused(host, turn)
    interruptions.judge(101.0, turn)
    assert not turn.held
    assert [type(message) for message in host.sent()] == [Interrupt]


def test_speech_that_ended_short_resumes_the_reply_and_is_never_sent() -> None:
    host = Host()
    turn = speech(200, ended=True)  # a cough
    interruptions, audio = paused(host, turn)
    assert interruptions.judge(101.0, None) is audio
    assert host.player() == [("pause", "talker-1", "barge_in"), ("resume", "talker-1", "false_barge_in")]
    assert host.counters.false_barge_ins == 1
    assert turn.held and host.sent() == [] and host.discarded == []
    assert not audio.cut and not interruptions.was_cut("r1") and not interruptions.pending


def test_a_false_verdict_while_the_user_still_talks_judges_the_same_utterance_again() -> None:
    host = Host()
    turn = speech(200)  # "yeah..."
    interruptions, audio = paused(host, turn)
    assert interruptions.judge(102.0, turn) is audio  # the window passed without proof
    assert host.player()[-1] == ("resume", "talker-1", "false_barge_in")
    assert interruptions.pending and interruptions.judges(turn) and turn.held
    assert interruptions.deadline() == 102.0 + 1.5  # a fresh window from the resume
    more(turn, 400)  # "... no wait, go left"
    assert interruptions.judge(102.5, turn) is audio
    # cut where it plays now (it played on since the resume), and counted false once only
    assert host.player() == [("interruption", "talker-1", "barge_in")]
    assert host.sent() == [Interrupt("r1", "item-r1", 2500), SendAudio(bytes(turn.audio))]
    assert host.counters.false_barge_ins == 1 and not turn.held and not interruptions.pending


def test_an_utterance_judged_again_that_ends_without_proof_is_dropped_and_the_reply_plays_on() -> None:
    host = Host()
    turn = speech(200)  # "yeah..."
    interruptions, audio = paused(host, turn)
    interruptions.judge(102.0, turn)
    host.player()
    turn.ended_at = 102.4  # "... right."
    assert interruptions.judge(102.5, None) is audio
    assert host.player() == [] and host.counters.false_barge_ins == 1  # resumed already, once
    assert turn.held and host.sent() == [] and not audio.cut and not interruptions.pending


def test_an_utterance_judged_again_is_an_ordinary_one_once_the_reply_is_over() -> None:
    for proof_ms in (400, 0):  # with proof (nothing left to cut) and without
        host = Host()
        turn = speech(200)
        interruptions, audio = paused(host, turn)
        interruptions.judge(102.0, turn)
        host.player()
        more(turn, proof_ms)
        assert interruptions.judge(105.5, turn) is audio  # the reply played out at 105 s
        assert host.player() == [] and not audio.cut, proof_ms
        assert host.sent() == [SendAudio(bytes(turn.audio))], proof_ms
        assert not turn.held and not interruptions.pending, proof_ms


def test_speech_judged_false_that_ended_is_not_judged_again() -> None:
    host = Host()
    turn = speech(200)
    interruptions, audio = paused(host, turn)
    turn.ended_at = 101.5
    interruptions.judge(102.0, None)  # no longer the utterance being received
    assert not interruptions.pending and turn.held and host.sent() == []


def test_the_held_speech_is_transcribed_once_long_enough_and_again_only_when_more_came() -> None:
    transcriber = Transcriber("no wait go left")
    host = Host(config=WORDS_DECIDE, transcriber=transcriber)
    turn = speech(300)
    interruptions, audio = paused(host, turn)
    assert interruptions.hearing() is None  # too little speech, whatever it says
    more(turn, 200)
    hearing = interruptions.hearing()
    assert hearing is not None
    assert interruptions.hearing() is None  # one transcription at a time
    heard = asyncio.run(hearing())
    assert transcriber.given == [(len(turn.audio), RATE)]
    assert heard.text == "no wait go left" and heard.covered_bytes == len(turn.audio)
    assert interruptions.heard(heard)
    assert interruptions.hearing() is None  # nothing new since
    more(turn, 100)
    assert interruptions.hearing() is not None
    assert interruptions.judge(101.0, turn) is audio and audio.cut


def test_the_transcriber_hears_the_speech_from_just_before_the_vads_onset() -> None:
    # Over a reply the VAD's 480 ms of pre-roll hold the robot's residual echo, which the
    # recogniser wrote as words: it hears from TRANSCRIBED_PRE_ROLL_MS before the onset on.
    transcriber = Transcriber("uh-huh")
    host = Host(config=WORDS_DECIDE, transcriber=transcriber)
    turn = Turn(2, "voice", 100.5, 1 << 22, utterance_id=2)
    turn.resampler = StreamResampler(16000, RATE)
    interruptions, _ = paused(host, turn)
    chunk = bytes(2 * 1600)  # 100 ms at 16 kHz, as the VAD sends it
    for sequence in range(10):  # 0.48 s of pre-roll, then speech
        pcm = turn.resample(chunk, 16000, False, unvoiced_samples=min(1600 * (sequence + 1), 7680))
        turn.add_audio(pcm)
    assert turn.pre_roll_ms == 480.0
    hearing = interruptions.hearing()
    assert hearing is not None
    heard = asyncio.run(hearing())
    skipped = 2 * int((480 - TRANSCRIBED_PRE_ROLL_MS) * RATE / 1000)
    assert transcriber.given == [(len(turn.audio) - skipped, RATE)]
    assert heard.covered_bytes == len(turn.audio)  # the transcript is of all the audio received


def test_backchannels_heard_over_the_reply_do_not_interrupt() -> None:
    host = Host(config=WORDS_DECIDE, transcriber=Transcriber("uh-huh yeah okay"))
    turn = speech(600, ended=True)
    interruptions, audio = paused(host, turn)
    hearing = interruptions.hearing()
    assert hearing is not None
    assert interruptions.heard(asyncio.run(hearing()))
    assert interruptions.judge(101.2, None) is audio
    assert not audio.cut and host.counters.false_barge_ins == 1


def test_without_its_words_the_speech_waits_for_them() -> None:
    host = Host(config=WORDS_DECIDE, transcriber=Transcriber("go left"))
    turn = speech(600)
    interruptions, _ = paused(host, turn)
    assert interruptions.judge(101.0, turn) is None  # long enough, but what did it say?


def test_a_failed_transcription_is_counted_and_the_speech_length_decides() -> None:
    host = Host(config=WORDS_DECIDE, transcriber=Transcriber(error=RuntimeError("decoder died")))
    turn = speech(600)
    interruptions, audio = paused(host, turn)
    hearing = interruptions.hearing()
    assert hearing is not None
    heard = asyncio.run(hearing())
    assert heard.text is None and host.counters.internal_errors == 1
    assert interruptions.heard(heard)
    assert interruptions.judge(101.0, turn) is audio and audio.cut


def test_words_heard_after_the_verdict_are_ignored() -> None:
    host = Host(config=WORDS_DECIDE, transcriber=Transcriber("go left now"))
    turn = speech(600)
    interruptions, audio = paused(host, turn)
    hearing = interruptions.hearing()
    assert hearing is not None
    interruptions.safety_stop(audio, 101.0)  # settled meanwhile
    heard = asyncio.run(hearing())
    assert not interruptions.heard(heard)
    assert heard.barge.words is None and heard.barge.transcribed_bytes == 0


def test_with_no_transcriber_or_no_words_asked_the_speech_length_alone_decides() -> None:
    for host in (
        Host(config=WORDS_DECIDE, transcriber=None),
        Host(config=LENGTH_DECIDES, transcriber=Transcriber("uh-huh")),
    ):
        turn = speech(500)
        interruptions, audio = paused(host, turn)
        assert interruptions.hearing() is None
        assert interruptions.judge(100.8, turn) is audio and audio.cut
    assert host.transcriber is not None and host.transcriber.given == []


def test_a_model_that_yielded_has_its_reply_cut_where_it_plays() -> None:
    host = Host()
    audio = reply()
    host.interruptions().model_yielded(audio, 101.25)
    assert host.player() == [("interruption", "talker-1", "model_yielded")]
    assert host.sent() == [Interrupt("r1", "item-r1", 1250)]
    assert host.counters.barge_ins == 1 and audio.cut


def test_a_safety_stop_cuts_the_reply_and_settles_the_barge_in_without_sending_the_speech() -> None:
    host = Host()
    turn = speech(300)
    interruptions, audio = paused(host, turn)
    host.player()
    assert interruptions.safety_stop(audio, 101.0) == 1000  # the player stopped at once: all heard
    assert host.player() == [("interruption", "talker-1", "safety_stop")]
    assert host.sent() == [Interrupt("r1", "item-r1", 1000)]  # the held speech (the stop) is not sent
    assert not turn.held and not interruptions.pending and interruptions.was_cut("r1")


def test_a_safety_stop_cuts_no_reply_already_cut_or_never_published() -> None:
    host = Host()
    interruptions = host.interruptions()
    cut = reply()
    cut.cut = True
    silent = reply()
    silent.stream_started_at = None
    assert interruptions.safety_stop(None, 101.0) is None
    assert interruptions.safety_stop(cut, 101.0) is None
    assert interruptions.safety_stop(silent, 101.0) is None
    assert host.player() == [] and host.sent() == [] and not silent.cut


def test_the_latest_responses_cut_are_remembered() -> None:
    host = Host()
    interruptions = host.interruptions()
    for n in range(RECENT_CUTS + 1):
        audio = reply()
        audio.response_id = f"r{n}"
        interruptions.model_yielded(audio, 101.0)
    assert not interruptions.was_cut("r0") and interruptions.was_cut("r1")
    assert interruptions.was_cut(f"r{RECENT_CUTS}")


# --- through the runtime -------------------------------------------------------------------------


async def speech_over_the_first_reply(agent, seconds: float) -> str:  # type: ignore[no-untyped-def]
    """A first turn whose reply is playing, then `seconds` of speech over it (end marker last);
    the reply's stream."""
    await speak(agent.port, 1, seconds=0.3)
    await asyncio.sleep(0.5)
    [stream] = agent.port.streams()
    agent.port.push(playing(stream, 300))
    agent.port.push(VoiceActivity(True))
    await speak(agent.port, 2, seconds=seconds)
    return stream


def test_speech_confirmed_by_its_words_after_it_ended_is_the_users_turn() -> None:
    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", seconds=2.0), spoken_reply("r2", seconds=0.2))
        slow = Transcriber("no wait go left", decode_s=0.8)  # its words come after the end marker
        async with running_agent(WORDS_DECIDE, factory, transcriber=slow) as agent:
            stream = await speech_over_the_first_reply(agent, seconds=0.6)
            assert agent.port.of("interruption") == []  # ended, and still judged
            await asyncio.sleep(1.5)
            await agent.stop()
        assert agent.port.of("interruption") == [(stream, "barge_in")]
        assert factory.last.names().count("end_of_turn") == 2  # committed once confirmed
        assert len(agent.port.streams()) == 2
        assert [(t.turn, t.outcome) for t in agent.port.turns()][-1] == (2, "completed")

    run_virtual(scenario())


def test_a_reply_generated_while_it_is_paused_ends_as_its_verdict_says() -> None:
    async def scenario() -> None:
        # r1 is generated in real time: its end comes while the barge-in waits for its words
        factory = FakeFactory(spoken_reply("r1", seconds=2.0, pace_s=0.2), spoken_reply("r2", seconds=0.2))
        slow = Transcriber("no wait go left", decode_s=1.0)
        async with running_agent(WORDS_DECIDE, factory, transcriber=slow) as agent:
            stream = await speech_over_the_first_reply(agent, seconds=1.0)
            await asyncio.sleep(2.0)
            await agent.stop()
        assert agent.port.of("interruption") == [(stream, "barge_in")]
        assert [t.outcome for t in agent.port.turns()] == ["interrupted", "completed"]

    run_virtual(scenario())
