"""The GPT-Live emulator against the official SDK's own client (`client.live.connect()`), on a thread."""

from __future__ import annotations

import asyncio
import base64
import json
import signal
import subprocess
import sys
from collections.abc import AsyncIterator, Callable, Coroutine
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from openai import AsyncOpenAI
from openai.resources.live.live import AsyncLiveConnection
from openai.types.live import (
    DelegationCreatedEvent,
    ErrorEvent,
    InputTranscriptDeltaEvent,
    OutputAudioDeltaEvent,
    OutputTranscriptDeltaEvent,
    ServerEvent,
    SessionClosedEvent,
    SessionStartedEvent,
    SessionUsageUpdatedEvent,
)
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosedError, InvalidStatus

from by_your_command.emulators.gpt_live import GptLiveEmulator, start
from by_your_command.emulators.gpt_live_script import (
    Delegate,
    Say,
    Script,
    ScriptError,
    Silence,
    Turn,
    load_script,
    script_from_mapping,
)
from by_your_command.emulators.synthetic_speech import speech_pcm
from by_your_command.emulators.threaded import ThreadedEmulator

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

MODEL = "gpt-live-1"


class Emulator(ThreadedEmulator[GptLiveEmulator]):
    def received_types(self) -> list[str]:
        return self._read(self.handle.received_types)

    def interrupted(self) -> list[str]:
        return self._read(lambda: [interruption.said for interruption in self.handle.interruptions])

    def stop(self) -> None:
        super().stop()
        self._loop.close()  # stopped and joined by now


def run(script: Script, body: Callable[[Emulator], Coroutine[Any, Any, None]]) -> None:
    with Emulator(start(script=script)) as emulator:
        asyncio.run(asyncio.wait_for(body(emulator), 15))


@asynccontextmanager
async def live(
    emulator: Emulator, api_key: str = "sk-test", **session: Any
) -> AsyncIterator[tuple[AsyncLiveConnection, SessionStartedEvent]]:
    """A started session over the SDK's connection."""
    client = AsyncOpenAI(api_key=api_key, base_url=emulator.handle.base_url)
    async with client.live.connect() as connection:
        config: Any = {"model": MODEL, **session}
        await connection.session.start(session=config, event_id="evt_start")
        started = await connection.recv()
        assert isinstance(started, SessionStartedEvent), started
        yield connection, started


async def until(connection: AsyncLiveConnection, done: Callable[[ServerEvent], bool]) -> list[ServerEvent]:
    """Every event up to and including the first for which `done` holds."""
    events: list[ServerEvent] = []
    async for event in connection:
        events.append(event)
        if done(event):
            return events
    raise AssertionError(f"connection closed before the awaited event: {[e.type for e in events]}")


def of_type(kind: str) -> Callable[[ServerEvent], bool]:
    return lambda event: event.type == kind


def said(events: list[ServerEvent]) -> str:
    return "".join(event.delta for event in events if isinstance(event, OutputTranscriptDeltaEvent))


def heard(events: list[ServerEvent]) -> str:
    return "".join(event.delta for event in events if isinstance(event, InputTranscriptDeltaEvent))


def audio_bytes(events: list[ServerEvent]) -> int:
    return sum(len(base64.b64decode(e.delta)) for e in events if isinstance(e, OutputAudioDeltaEvent))


def saying(text: str, transcript: list[str]) -> Callable[[ServerEvent], bool]:
    """Done once the output transcript (gathered in `transcript`) reaches `text`."""

    def done(event: ServerEvent) -> bool:
        if isinstance(event, OutputTranscriptDeltaEvent):
            transcript.append(event.delta)
        return "".join(transcript).endswith(text)

    return done


def pcm(ms: int, loud: bool, rate: int = 24_000) -> str:
    t = np.arange(rate * ms // 1000) / rate
    samples = 8000 * np.sin(2 * np.pi * 220 * t) if loud else np.zeros_like(t)
    return base64.b64encode(samples.astype("<i2").tobytes()).decode()


async def speak(connection: AsyncLiveConnection, speech_ms: int = 400, rate: int = 24_000) -> None:
    """A user utterance: speech, then enough quiet to end the turn."""
    await connection.session.input_audio.append(audio=pcm(speech_ms, True, rate))
    await connection.session.input_audio.append(audio=pcm(600, False, rate))


def test_a_spoken_turn_is_answered_with_paced_audio_and_transcripts() -> None:
    script = Script(turns=(Turn(Say("Hi there"), heard="hello robot"), Turn(Say("unused"))), pace=0.05)

    async def body(emulator: Emulator) -> None:
        async with live(
            emulator, audio={"format": {"type": "audio/pcm", "rate": 16_000}, "output": {"voice": "cedar"}}
        ) as (connection, started):
            assert started.client_event_id == "evt_start"
            assert started.session.model == MODEL and started.session.status == "active"
            assert started.session.audio is not None and started.session.audio.format is not None
            assert started.session.audio.format.rate == 16_000
            assert started.session.audio.output is not None and started.session.audio.output.voice == "cedar"
            # A noise shorter than 300 ms is no turn; the utterance after it is.
            await connection.session.input_audio.append(audio=pcm(150, True, 16_000))
            await connection.session.input_audio.append(audio=pcm(600, False, 16_000))
            await speak(connection, rate=16_000)
            transcript: list[str] = []
            events = await until(connection, saying("Hi there", transcript))
            assert heard(events) == "hello robot"
            assert said(events) == "Hi there"
            assert audio_bytes(events) == len(speech_pcm("Hi there", 60, 16_000))
            first_output = next(i for i, e in enumerate(events) if isinstance(e, OutputAudioDeltaEvent))
            last_input = max(i for i, e in enumerate(events) if isinstance(e, InputTranscriptDeltaEvent))
            assert last_input < first_output  # the model answers once the user finished
            deltas = [e for e in events if isinstance(e, OutputTranscriptDeltaEvent)]
            assert all(a.end_ms <= b.start_ms for a, b in zip(deltas, deltas[1:], strict=False))

    run(script, body)


def test_user_speech_over_a_reply_interrupts_it() -> None:
    story = "Once upon a time there was a robot who loved to talk for a long while."
    script = Script(
        turns=(Turn(Say(story), heard="tell me a story"), Turn(Say("Okay."), heard="stop")), pace=1.0
    )

    async def body(emulator: Emulator) -> None:
        async with live(emulator) as (connection, _):
            await speak(connection)
            await until(connection, lambda event: isinstance(event, OutputAudioDeltaEvent))
            await speak(connection)  # talks over the story
            transcript: list[str] = []
            events = await until(connection, saying("Okay.", transcript))
            cut = "".join(transcript)[: -len("Okay.")]
            assert story.startswith(cut) and len(cut) < len(story)  # the story stopped where it was
            assert heard(events) == "stop"
            assert emulator.interrupted() == [cut]

    run(script, body)


def test_a_turn_that_talks_on_finishes_before_answering_the_speech_over_it() -> None:
    script = Script(
        turns=(
            Turn(Say("I will finish this."), heard="go on", interruptible=False),
            Turn(Say("Yes?"), heard="wait"),
        ),
        pace=1.0,
    )

    async def body(emulator: Emulator) -> None:
        async with live(emulator) as (connection, _):
            await speak(connection)
            await until(connection, lambda event: isinstance(event, OutputAudioDeltaEvent))
            await speak(connection)
            transcript: list[str] = []
            events = await until(connection, saying("Yes?", transcript))
            assert "".join(transcript) == "I will finish this.Yes?"
            assert emulator.interrupted() == []
            assert heard(events) == "wait"

    run(script, body)


def test_client_delegation_round_trip() -> None:
    script = Script(
        turns=(
            Turn(Delegate(Say("One moment."), Say("I waved.")), heard="please wave"),
            Turn(Delegate(Say("Let me see.")), heard="what time is it"),
        ),
        pace=0.0,
    )

    async def body(emulator: Emulator) -> None:
        async with live(emulator) as (connection, started):
            assert started.session.delegation is not None and started.session.delegation.type == "client"
            await speak(connection)
            transcript: list[str] = []
            events = await until(connection, saying("One moment.", transcript))
            created = next(e for e in events if isinstance(e, DelegationCreatedEvent))
            assert created.delegation.target == "client" and created.delegation.type == "delegation"
            assert heard(events) == "please wave"
            delegation_id = created.delegation.id
            await connection.session.thinking.append(content="waving now", delegation_id=delegation_id)
            await until(connection, of_type("session.thinking.appended"))
            await connection.session.commentary.append(
                content="The robot waved.", delegation_id=delegation_id, event_id="evt_result"
            )
            acked = await until(connection, of_type("session.commentary.appended"))
            assert acked[-1].client_event_id == "evt_result"  # type: ignore[union-attr]
            transcript.clear()
            await until(connection, saying("I waved.", transcript))
            # An id the server never gave is refused.
            await connection.session.commentary.append(content="x", delegation_id="dlg_unknown")
            error = (await until(connection, of_type("error")))[-1]
            assert isinstance(error, ErrorEvent) and error.error.param == "delegation_id"

        async with live(emulator, delegation={"type": "client", "acknowledgement_delay_ms": 5000}) as (
            connection,
            _,
        ):
            await speak(connection)
            second = (await until(connection, of_type("session.delegation.created")))[-1]
            assert isinstance(second, DelegationCreatedEvent)
            # The result comes before the acknowledgement delay: no acknowledgement, and without a
            # scripted answer the model speaks the commentary as given.
            await connection.session.commentary.append(
                content="It is noon.", delegation_id=second.delegation.id
            )
            transcript = []
            await until(connection, saying("It is noon.", transcript))
            assert "".join(transcript) == "It is noon."

    run(script, body)


def test_muted_input_is_heard_as_silence() -> None:
    script = Script(turns=(Turn(Say("First."), heard="after unmute"), Turn(Say("Second."))), pace=0.0)

    async def body(emulator: Emulator) -> None:
        async with live(emulator) as (connection, _):
            await connection.session.input_audio.mute(event_id="evt_mute")
            muted = (await until(connection, of_type("session.input_audio.muted")))[-1]
            assert muted.client_event_id == "evt_mute"  # type: ignore[union-attr]
            await speak(connection)  # muted: no turn
            await connection.session.input_audio.unmute()
            unmuted = await until(connection, of_type("session.input_audio.unmuted"))
            assert heard(unmuted) == ""
            await speak(connection)
            transcript: list[str] = []
            events = await until(connection, saying("First.", transcript))
            assert heard(events) == "after unmute"
        assert emulator.received_types().count("session.input_audio.append") == 4

    run(script, body)


def test_usage_counts_every_open_second_and_close_reports_the_total() -> None:
    script = Script(usage_interval_ms=100)

    async def body(emulator: Emulator) -> None:
        async with live(emulator) as (connection, _):  # no audio at all: silence is billed too
            events = await until(
                connection, lambda e: isinstance(e, SessionUsageUpdatedEvent) and e.usage.seconds >= 1
            )
            seconds = [e.usage.seconds for e in events if isinstance(e, SessionUsageUpdatedEvent)]
            assert seconds == sorted(seconds)
            await connection.session.close(event_id="evt_close")
            closed = (await until(connection, of_type("session.closed")))[-1]
            assert isinstance(closed, SessionClosedEvent)
            assert closed.reason == "close_requested" and closed.client_event_id == "evt_close"
            assert closed.usage.seconds >= seconds[-1]
            assert [event async for event in connection] == []  # then the server closes

    run(script, body)


def test_session_start_comes_first_and_is_checked_against_the_sdk_types() -> None:
    async def body(emulator: Emulator) -> None:
        client = AsyncOpenAI(api_key="sk-test", base_url=emulator.handle.base_url)
        async with client.live.connect() as connection:
            await connection.session.start(
                session={"model": MODEL, "voice": "marin"},  # type: ignore[typeddict-unknown-key]
                event_id="evt_bad",
            )
            error = await connection.recv()
            assert isinstance(error, ErrorEvent)
            assert error.error.code == "unknown_parameter" and error.error.param == "session.voice"
            assert error.error.type == "invalid_request_error" and error.error.client_event_id == "evt_bad"
            assert [event async for event in connection] == []  # refused before start: closed
        async with client.live.connect() as connection:
            await connection.session.input_audio.append(audio=pcm(100, False))
            error = await connection.recv()
            assert isinstance(error, ErrorEvent) and error.error.code == "session_not_started"
            assert [event async for event in connection] == []
        async with live(emulator) as (connection, _):
            await connection.response.create()  # Responses delegation only
            await connection.send({"type": "session.nonsense"})  # type: ignore[arg-type]
            await connection.session.input_audio.append(audio="not base64!")
            errors = await until(connection, lambda e: isinstance(e, ErrorEvent) and e.error.param == "audio")
            messages = [e.error.message for e in errors if isinstance(e, ErrorEvent)]
            assert messages[0] == "response.create requires Responses delegation."
            assert "Unknown event type" in messages[1]
            await connection.session.close()
            await until(connection, of_type("session.closed"))

    run(Script(), body)


def test_hostile_frames_get_errors_and_the_session_lives_on() -> None:
    async def body(emulator: Emulator) -> None:
        url = emulator.handle.websocket_base_url + "/live/sessions"
        async with connect(url, additional_headers={"Authorization": "Bearer sk-test"}) as ws:
            await ws.send(json.dumps({"type": "session.start", "session": {"model": MODEL}}))
            assert json.loads(await ws.recv())["type"] == "session.started"
            deep = '{"a":' + "[" * 40 + "1" + "]" * 40 + "}"
            for frame in (
                "{",
                b"\x00",
                "[1]",
                deep,
                json.dumps({"type": "session.input_audio.append", "audio": "AAAA"}),
            ):
                await ws.send(frame)
                assert json.loads(await ws.recv())["type"] == "error"
            update = {"delegation": {"type": "client", "acknowledgement_delay_ms": 250}}
            await ws.send(json.dumps({"type": "session.update", "session": update, "event_id": "evt_u"}))
            updated = json.loads(await ws.recv())
            assert updated["type"] == "session.updated" and updated["client_event_id"] == "evt_u"
            assert updated["session"]["delegation"] == {"type": "client", "acknowledgement_delay_ms": 250}
        assert emulator._read(lambda: emulator.handle.handshakes[0].path) == "/v1/live/sessions"
        assert all(
            "authorization" not in h.headers for h in emulator._read(lambda: emulator.handle.handshakes)
        )

    run(Script(usage_interval_ms=60_000), body)  # no usage event in between


def test_a_revoked_key_fails_the_handshake_with_401() -> None:
    async def body(emulator: Emulator) -> None:
        client = AsyncOpenAI(api_key="sk-revoked-1234", base_url=emulator.handle.base_url)
        with pytest.raises(InvalidStatus) as refused:
            async with client.live.connect():
                pass
        assert refused.value.response.status_code == 401
        assert b"invalid_api_key" in refused.value.response.body and b"1234" in refused.value.response.body

    run(Script(rejected_api_keys=("sk-revoked-1234",)), body)


def test_scripted_server_close_dropped_connection_and_a_model_that_speaks_first() -> None:
    script = Script(
        turns=(
            Turn(Say("Still there?"), after_ms=50),
            Turn(Say("A long story that gets stopped."), close_after_ms=300),
            Turn(Say("A long story that gets dropped."), drop_after_ms=300),
        ),
        pace=0.0,
    )

    async def body(emulator: Emulator) -> None:
        async with live(emulator) as (connection, _):
            transcript: list[str] = []
            events = await until(connection, saying("Still there?", transcript))
            assert heard(events) == ""  # nobody spoke: the model started
            await speak(connection)
            closed = (await until(connection, of_type("session.closed")))[-1]
            assert isinstance(closed, SessionClosedEvent) and closed.reason == "content"
            assert [event async for event in connection] == []
        async with live(emulator) as (connection, _):
            await speak(connection)
            with pytest.raises(ConnectionClosedError):
                async for _event in connection:
                    pass

    run(script, body)


def test_the_documented_script_loads_and_mistakes_are_named(tmp_path: Path) -> None:
    from by_your_command.emulators import gpt_live_script

    doc = gpt_live_script.__doc__ or ""
    example = doc[doc.index("    pace:") :]
    path = tmp_path / "script.yaml"
    path.write_text("\n".join(line[4:] for line in example.splitlines()))
    script = load_script(path)
    assert script.turns[1] == Turn(Delegate(Say("Sure, one moment."), Say("I waved.")), heard="please wave")
    assert script.turns[4].reply == Silence() and script.turns[3].after_ms == 5000
    assert script.rejected_api_keys == ("sk-revoked",)
    for raw, complaint in (
        ({"turns": [{"say": "x", "then": "y"}]}, "only follows a delegation"),
        ({"turns": [{"say": "x", "silent": True}]}, "exactly one"),
        ({"turns": [{"say": "x", "shout": 1}]}, "unknown key"),
        ({"pace": -1}, "pace"),
    ):
        with pytest.raises(ScriptError, match=complaint):
            script_from_mapping(raw)


def test_byc_emulate_gpt_live_serves_until_ctrl_c(tmp_path: Path) -> None:
    script = tmp_path / "script.yaml"
    script.write_text("turns: [{say: pong, after_ms: 10}]\npace: 0\n")
    command = [
        sys.executable,
        "-m",
        "by_your_command.cli.emulate",
        "gpt-live",
        "--port",
        "0",
        "--script",
        str(script),
    ]
    with subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as process:
        _serve_and_ping(process)


def _serve_and_ping(process: subprocess.Popen[str]) -> None:
    try:
        assert process.stdout is not None and process.stderr is not None
        first = process.stdout.readline()
        assert "/live/sessions" in first, first + (
            process.stderr.read() if process.poll() is not None else ""
        )
        line = next(line for line in iter(process.stdout.readline, "") if "OPENAI_BASE_URL=" in line)
        base_url = line.split("OPENAI_BASE_URL=", 1)[1].strip()

        async def ping() -> str:
            client = AsyncOpenAI(api_key="sk-emulator", base_url=base_url)
            async with client.live.connect() as connection:
                await connection.session.start(session={"model": MODEL})
                transcript: list[str] = []
                await until(connection, saying("pong", transcript))
                return "".join(transcript)

        assert asyncio.run(asyncio.wait_for(ping(), 15)) == "pong"
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=15) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
