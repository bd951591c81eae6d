"""The Gemini Live emulator's own rules, over real loopback WebSockets with raw frames.

Plain ws:// here (tls=False) unless TLS is the point; the provider tests drive it through the
official SDK over TLS.
"""

from __future__ import annotations

import asyncio
import base64
import json
from collections.abc import AsyncIterator, Callable, Coroutine
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import pytest
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from by_your_command.emulators.gemini_live import GeminiLiveEmulator, start
from by_your_command.emulators.gemini_script import (
    CallTool,
    Say,
    Script,
    ScriptError,
    Silence,
    Turn,
    load_script,
    script_from_mapping,
)

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

MANUAL_SETUP = {
    "setup": {
        "model": "models/gemini-3.8-live",
        "realtimeInputConfig": {"automaticActivityDetection": {"disabled": True}},
        "inputAudioTranscription": {},
        "outputAudioTranscription": {},
    }
}


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def run(
    body: Callable[[GeminiLiveEmulator], Coroutine[Any, Any, None]],
    script: Script | None = None,
    tls: bool = False,
    clock: Clock | None = None,
) -> None:
    async def main() -> None:
        emulator = await start(script=script, tls=tls, clock=clock or Clock())
        try:
            await body(emulator)
        finally:
            await emulator.stop()

    asyncio.run(asyncio.wait_for(main(), 30))


@asynccontextmanager
async def client(
    emulator: GeminiLiveEmulator, setup: dict[str, Any] | None = None, key: str = "test-key"
) -> AsyncIterator[ClientConnection]:
    async with connect(
        emulator.websocket_url, additional_headers={"x-goog-api-key": key} if key else {}
    ) as ws:
        await ws.send(json.dumps(setup or MANUAL_SETUP))
        assert json.loads(await ws.recv()) == {"setupComplete": {}}
        yield ws


async def refusal(emulator: GeminiLiveEmulator, first: str | bytes, key: str = "test-key") -> tuple[int, str]:
    """The close code and reason the server answers `first` with."""
    async with connect(
        emulator.websocket_url, additional_headers={"x-goog-api-key": key} if key else {}
    ) as ws:
        await ws.send(first)
        with pytest.raises(ConnectionClosed) as closed:
            while True:
                await ws.recv()
        assert closed.value.rcvd is not None
        return closed.value.rcvd.code, closed.value.rcvd.reason


async def messages_until(
    ws: ClientConnection, done: Callable[[dict[str, Any]], bool]
) -> list[dict[str, Any]]:
    got: list[dict[str, Any]] = []
    while True:
        message: dict[str, Any] = json.loads(await ws.recv())
        got.append(message)
        if done(message):
            return got


def turn_complete(message: dict[str, Any]) -> bool:
    return bool(message.get("serverContent", {}).get("turnComplete"))


def audio_message(ms: int, urlsafe: bool = True, key: str = "audio") -> str:
    pcm = b"\xfb\xff" * (16 * ms)  # encodes to '-' / '_' in the URL-safe alphabet
    encode = base64.urlsafe_b64encode if urlsafe else base64.b64encode
    return json.dumps(
        {"realtime_input": {key: {"data": encode(pcm).decode(), "mime_type": "audio/pcm;rate=16000"}}}
    )


def activity(name: str) -> str:
    return json.dumps({"realtimeInput": {name: {}}})


def test_voice_turn_accepts_snake_case_and_url_safe_base64() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator) as ws:
            await ws.send(json.dumps({"realtime_input": {"activity_start": {}}}))
            await ws.send(audio_message(300))
            await ws.send(activity("activityEnd"))
            got = await messages_until(ws, turn_complete)
        heard = "".join(
            m["serverContent"]["inputTranscription"]["text"]
            for m in got
            if "inputTranscription" in m.get("serverContent", {})
        )
        assert heard == "hello robot"
        audio = [m for m in got if "modelTurn" in m.get("serverContent", {})]
        assert {m["serverContent"]["modelTurn"]["parts"][0]["inlineData"]["mimeType"] for m in audio} == {
            "audio/pcm;rate=24000"
        }
        kinds = [next(iter(m["serverContent"])) for m in got if "serverContent" in m]
        assert kinds[-2:] == ["generationComplete", "turnComplete"]
        assert emulator.sessions[0].conversation.audio_ms == 300  # decoded right, not corrupted
        assert [r.kind for r in emulator.received] == [
            "setup",
            "realtimeInput",
            "realtimeInput",
            "realtimeInput",
        ]

    run(body)


def test_activity_start_during_a_reply_interrupts_it() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator) as ws:
            await ws.send(
                json.dumps(
                    {
                        "clientContent": {
                            "turns": [{"role": "user", "parts": [{"text": "go"}]}],
                            "turnComplete": True,
                        }
                    }
                )
            )
            await ws.send(activity("activityStart"))
            got = await messages_until(ws, turn_complete)
        contents = [m["serverContent"] for m in got]
        assert contents[-2:] == [{"interrupted": True}, {"turnComplete": True}]
        assert not [c for c in contents if "generationComplete" in c]
        assert "usageMetadata" in got[-1]

    run(body, Script(turns=(Turn(Silence()),)))


def test_usage_counts_frames_under_the_scripted_modality() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator) as ws:
            frame = base64.b64encode(b"\xff\xd8\xff\xd9").decode()
            await ws.send(json.dumps({"realtimeInput": {"video": {"data": frame, "mimeType": "image/jpeg"}}}))
            await ws.send(json.dumps({"realtimeInput": {"text": "what do you see"}}))
            got = await messages_until(ws, turn_complete)
        details = {d["modality"]: d["tokenCount"] for d in got[-1]["usageMetadata"]["promptTokensDetails"]}
        assert details["VIDEO"] == 100

    run(body, Script(frame_modality="VIDEO", image_tokens=100))


def test_tool_call_waits_for_a_matching_tool_response() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator) as ws:
            await ws.send(json.dumps({"realtimeInput": {"text": "wave"}}))
            call = json.loads(await ws.recv())["toolCall"]["functionCalls"][0]
            assert call["name"] == "robot_command" and call["args"] == {"command": "wave"}
            answer = {"id": call["id"], "name": "robot_command", "response": {"accepted": True}}
            await ws.send(json.dumps({"tool_response": {"function_responses": [answer]}}))
            got = await messages_until(ws, turn_complete)
            assert any("modelTurn" in m.get("serverContent", {}) for m in got)
            await ws.send(json.dumps({"toolResponse": {"functionResponses": [answer]}}))  # answered already
            with pytest.raises(ConnectionClosed) as closed:
                await messages_until(ws, lambda m: False)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1007

    run(body, Script(turns=(Turn(CallTool("robot_command", '{"command": "wave"}', Say("Done."))),)))


def test_activity_start_cancels_a_waiting_call_and_a_late_answer_is_ignored() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator) as ws:
            await ws.send(json.dumps({"realtimeInput": {"text": "wave"}}))
            call = json.loads(await ws.recv())["toolCall"]["functionCalls"][0]
            await ws.send(activity("activityStart"))  # the user cuts in before the result
            got = await messages_until(ws, turn_complete)
            assert got[0] == {"toolCallCancellation": {"ids": [call["id"]]}}
            answer = {"id": call["id"], "name": "robot_command", "response": {"accepted": True}}
            await ws.send(json.dumps({"toolResponse": {"functionResponses": [answer]}}))  # too late
            await ws.send(audio_message(200))
            await ws.send(activity("activityEnd"))
            reply = await messages_until(ws, turn_complete)  # the connection goes on
            assert any("modelTurn" in m.get("serverContent", {}) for m in reply)
        assert emulator.sessions[0].cancelled_responses == 1

    run(body, Script(turns=(Turn(CallTool("robot_command", '{"command": "wave"}')), Turn(Say("Yes?")))))


@pytest.mark.parametrize(
    ("first", "code"),
    [
        ("not json", 1007),
        (json.dumps({"clientContent": {"turns": []}}), 1007),  # setup must come first
        (json.dumps({"setup": {"model": "models/x"}, "clientContent": {}}), 1007),  # two kinds
        (json.dumps({"setup": {"model": "models/x", "bogusField": 1}}), 1007),
        (
            json.dumps(
                {"setup": {"model": "m", "generationConfig": {"responseModalities": ["AUDIO", "TEXT"]}}}
            ),
            1007,
        ),
        (json.dumps({"setup": {}}), 1007),
        (
            json.dumps(
                {
                    "setup": {
                        "model": "m",
                        "tools": [[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]],
                    }
                }
            ),
            1007,
        ),
    ],
)
def test_a_bad_first_frame_is_closed_1007(first: str, code: int) -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        assert (await refusal(emulator, first))[0] == code

    run(body)


def test_keys_and_models_are_refused_like_the_real_server() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        setup = json.dumps(MANUAL_SETUP)
        assert (await refusal(emulator, setup, key=""))[0] == 1008
        code, reason = await refusal(emulator, setup, key="revoked")
        assert (code, reason) == (1007, "API key not valid. Please pass a valid API key.")
        other = json.dumps({"setup": {"model": "models/gemini-0"}})
        code, reason = await refusal(emulator, other)
        assert code == 1008 and "not found" in reason
        assert all("test-key" not in str(h.headers) for h in emulator.handshakes)  # keys are not recorded

    run(body, Script(rejected_api_keys=("revoked",), known_models=("gemini-3.8-live",)))


def test_a_wrong_path_is_http_404() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        with pytest.raises(InvalidStatus) as refused:
            async with connect(f"ws://127.0.0.1:{emulator.port}/ws/other.Service"):
                pass
        assert refused.value.response.status_code == 404

    run(body)


def test_hostile_frames_close_1007_and_never_crash_the_server() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        bad_frames = [
            json.dumps({"realtimeInput": {"audio": {"data": "***", "mimeType": "audio/pcm"}}}),
            json.dumps({"realtimeInput": {"audio": {"data": "AAAA", "mimeType": "audio/pcm"}}}),  # odd bytes
            json.dumps({"realtimeInput": {"video": {"data": "AAAA", "mimeType": "text/html"}}}),
            json.dumps({"clientContent": {"turns": [{"role": "system", "parts": []}]}}),
            json.dumps({"realtimeInput": {"audio": "not an object"}}),
            json.dumps({"setup": {"model": "again"}}),
            b"\x00\xff binary garbage",
        ]
        for frame in bad_frames:
            async with client(emulator) as ws:
                await ws.send(frame)
                with pytest.raises(ConnectionClosed) as closed:
                    await messages_until(ws, lambda m: False)
                assert closed.value.rcvd is not None and closed.value.rcvd.code == 1007, frame
        async with client(emulator) as ws:  # still serving
            await ws.send(json.dumps({"realtimeInput": {"text": "hi"}}))
            await messages_until(ws, turn_complete)

    run(body)


def test_activity_markers_need_automatic_detection_disabled() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator, {"setup": {"model": "models/gemini-3.8-live"}}) as ws:
            await ws.send(activity("activityStart"))
            with pytest.raises(ConnectionClosed) as closed:
                await ws.recv()
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1007

    run(body)


def resumable(handle: str | None = None) -> dict[str, Any]:
    setup = json.loads(json.dumps(MANUAL_SETUP))
    setup["setup"]["sessionResumption"] = {"handle": handle} if handle else {}
    return setup


async def said_turn(ws: ClientConnection, text: str) -> str:
    """A text turn; returns the handle of the update that follows its turnComplete."""
    await ws.send(
        json.dumps(
            {"clientContent": {"turns": [{"role": "user", "parts": [{"text": text}]}], "turnComplete": True}}
        )
    )
    await messages_until(ws, turn_complete)
    update = json.loads(await ws.recv())["sessionResumptionUpdate"]
    assert update["resumable"] is True
    return str(update["newHandle"])


def test_resumption_handles_are_honoured_with_history_kept_and_expire() -> None:
    clock = Clock()

    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator, resumable()) as ws:
            await said_turn(ws, "first")
            handle = await said_turn(ws, "second")
            # Refused while the connection that issued it is still open.
            assert (await refusal(emulator, json.dumps(resumable(handle))))[0] == 1007
        async with client(emulator, resumable(handle)) as ws:
            await said_turn(ws, "third")
        said = [text for _, text in emulator.sessions[2].conversation.transcript]
        assert said == ["first", "One.", "second", "Two.", "third", "Three."]
        clock.now += 7201.0
        code, _ = await refusal(emulator, json.dumps(resumable(handle)))
        assert code == 1007
        assert (await refusal(emulator, json.dumps(resumable("never-issued"))))[0] == 1007

    run(body, Script(turns=(Turn(Say("One.")), Turn(Say("Two.")), Turn(Say("Three.")))), clock=clock)


def test_go_away_then_a_normal_close() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator) as ws:
            await ws.send(json.dumps({"realtimeInput": {"text": "hi"}}))
            got = await messages_until(ws, lambda m: "goAway" in m)
            assert got[-1] == {"goAway": {"timeLeft": "0s"}}
            with pytest.raises(ConnectionClosed) as closed:
                await messages_until(ws, lambda m: False)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1000

    run(body, Script(go_away_after_turns=1, go_away_time_left_s=0.0))


def test_the_deadline_closes_1011() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator) as ws:
            with pytest.raises(ConnectionClosed) as closed:
                await messages_until(ws, lambda m: False)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1011
        assert closed.value.rcvd.reason.startswith("Deadline expired")

    run(body, Script(deadline_s=0.01))


def test_drop_after_ms_aborts_the_connection_without_a_close_frame() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        async with client(emulator) as ws:
            await ws.send(json.dumps({"realtimeInput": {"text": "hi"}}))
            with pytest.raises(ConnectionClosed) as closed:
                await messages_until(ws, lambda m: False)
        assert closed.value.rcvd is None

    run(body, Script(turns=(Turn(Say("A long story about robots."), drop_after_ms=100),)))


def test_tls_serves_with_a_certificate_the_client_can_trust() -> None:
    async def body(emulator: GeminiLiveEmulator) -> None:
        assert emulator.base_url.startswith("https://") and emulator.cert_file is not None
        async with connect(
            emulator.websocket_url,
            ssl=emulator.client_ssl_context(),
            additional_headers={"x-goog-api-key": "k"},
        ) as ws:
            await ws.send(json.dumps(MANUAL_SETUP))
            assert json.loads(await ws.recv()) == {"setupComplete": {}}

    run(body, tls=True)


def test_script_yaml_loads_and_names_the_bad_place(tmp_path: Path) -> None:
    path = tmp_path / "script.yaml"
    path.write_text(
        "pace: 0\ngo_away_after_turns: 2\nframe_modality: VIDEO\n"
        "turns:\n  - {heard: hi, say: Hello.}\n  - tool: {name: robot_command, arguments: {command: wave}}\n"
        "    then: {say: Waved.}\n  - {silent: true}\n  - {text: Only text., close_after_ms: 10}\n"
    )
    script = load_script(path)
    assert script.go_away_after_turns == 2 and script.frame_modality == "VIDEO"
    assert script.turns[0] == Turn(Say("Hello."), heard="hi")
    assert script.turns[1].reply == CallTool("robot_command", '{"command": "wave"}', Say("Waved."))
    assert script.turns[2].reply == Silence()
    assert script.turns[3] == Turn(Say("Only text.", "text"), close_after_ms=10)
    for bad, where in [
        ({"turns": [{"say": "a", "text": "b"}]}, "turns[0]"),
        ({"pace": "fast"}, "script.pace"),
        ({"bogus": 1}, "unknown key"),
        ({"frame_modality": "AUDIO"}, "frame_modality"),
        ({"turns": [{"say": "a", "then": "b"}]}, "then"),
    ]:
        with pytest.raises(ScriptError, match=where.replace("[", r"\[").replace("]", r"\]")):
            script_from_mapping(bad)


def test_a_tool_turn_can_script_a_cancellation() -> None:
    script = script_from_mapping(
        {
            "turns": [
                {"tool": {"name": "robot_command", "arguments": {"command": "wave"}}, "cancel_after_ms": 250}
            ]
        }
    )
    assert script.turns[0].cancel_after_ms == 250 and isinstance(script.turns[0].reply, CallTool)
    for bad, where in [
        ({"turns": [{"say": "a", "cancel_after_ms": 5}]}, "cancel_after_ms needs a tool turn"),
        ({"turns": [{"tool": {"name": "robot_command"}, "cancel_after_ms": -1}]}, ">= 0 ms"),
        ({"turns": [{"tool": {"name": "robot_command"}, "cancel_after_ms": "soon"}]}, "cancel_after_ms"),
    ]:
        with pytest.raises(ScriptError, match=where):
            script_from_mapping(bad)
