"""The OpenAI Realtime emulator's own rules, over real loopback WebSockets (raw frames and the SDK)."""

from __future__ import annotations

import asyncio
import base64
import json
from collections.abc import AsyncIterator, Callable, Coroutine
from contextlib import asynccontextmanager
from typing import Any

import pytest
from openai import AsyncOpenAI
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from by_your_command.emulators.openai_realtime import OpenAIRealtimeEmulator, start
from by_your_command.emulators.openai_script import CallTool, Say, Script, Silence, Turn

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


def run(
    body: Callable[[OpenAIRealtimeEmulator], Coroutine[Any, Any, None]], script: Script | None = None
) -> None:
    async def main() -> None:
        emulator = await start(script=script)
        try:
            await body(emulator)
        finally:
            await emulator.stop()

    asyncio.run(asyncio.wait_for(main(), 30))


@asynccontextmanager
async def raw_client(
    emulator: OpenAIRealtimeEmulator, headers: dict[str, str] | None = None
) -> AsyncIterator[ClientConnection]:
    url = emulator.websocket_base_url + "/realtime?model=gpt-realtime-2.1"
    async with connect(url, additional_headers=headers or {"Authorization": "Bearer sk-test"}) as ws:
        created = json.loads(await ws.recv())
        assert created["type"] == "session.created"
        yield ws


async def next_of(ws: ClientConnection, wanted: str) -> dict[str, Any]:
    """The next server event of type `wanted` (others are skipped)."""
    while True:
        event: dict[str, Any] = json.loads(await ws.recv())
        if event["type"] == wanted:
            return event


def audio_b64(ms: int) -> str:
    return base64.b64encode(b"\x10\x00" * (24 * ms)).decode()


def append(ms: int) -> str:
    return json.dumps({"type": "input_audio_buffer.append", "audio": audio_b64(ms)})


MANUAL = json.dumps(
    {"type": "session.update", "session": {"type": "realtime", "audio": {"input": {"turn_detection": None}}}}
)


def test_commit_needs_100_ms_of_audio() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        async with raw_client(emulator) as ws:
            await ws.send(append(60))
            await ws.send(json.dumps({"type": "input_audio_buffer.commit", "event_id": "evt_short"}))
            error = await next_of(ws, "error")
            assert error["error"]["code"] == "input_audio_buffer_commit_empty"
            assert error["error"]["event_id"] == "evt_short"
            await ws.send(append(60))  # the buffer kept the first 60 ms
            await ws.send(json.dumps({"type": "input_audio_buffer.commit"}))
            committed = await next_of(ws, "input_audio_buffer.committed")
            added = await next_of(ws, "conversation.item.added")
            assert added["item"]["id"] == committed["item_id"] and added["item"]["role"] == "user"

    run(body)


def test_one_active_response_and_cancel_rules() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        async with raw_client(emulator) as ws:
            await ws.send(json.dumps({"type": "response.create"}))
            created = await next_of(ws, "response.created")
            await ws.send(json.dumps({"type": "response.create"}))
            error = await next_of(ws, "error")
            assert error["error"]["code"] == "conversation_already_has_active_response"
            await ws.send(json.dumps({"type": "response.cancel"}))
            done = await next_of(ws, "response.done")
            assert done["response"]["id"] == created["response"]["id"]
            assert done["response"]["status"] == "cancelled"
            await ws.send(json.dumps({"type": "response.cancel"}))
            error = await next_of(ws, "error")
            assert error["error"]["code"] == "response_cancel_not_active"
            await ws.send(json.dumps({"type": "response.create"}))  # free again after the cancel
            assert (await next_of(ws, "response.created"))["response"]["id"] != created["response"]["id"]

    run(body, Script(turns=(Turn(Silence()), Turn(Silence()))))


@pytest.mark.parametrize(
    ("frame", "code"),
    [
        ("not json", "invalid_json"),
        ("[1, 2]", "invalid_request_error"),
        ('{"event_id": "x"}', "missing_required_parameter"),
        ('{"type": "no.such.event"}', "invalid_value"),
        ('{"type": "input_audio_buffer.append", "audio": "***"}', "invalid_value"),
        ('{"type": "input_audio_buffer.append", "audio": 5}', "invalid_type"),
        ('{"type": "session.update", "session": {"instructions": "hi"}}', "missing_required_parameter"),
        (
            '{"type": "session.update", "session": {"type": "realtime", "temperature": 0.8}}',
            "unknown_parameter",
        ),
        (
            '{"type": "conversation.item.create", "item": {"type": "message", "role": "robot"}}',
            "invalid_value",
        ),
        ('{"type": "conversation.item.delete", "item_id": "item_nope"}', "item_not_found"),
        ("[" * 100 + "]" * 100, "invalid_request_error"),
    ],
)
def test_malformed_frames_get_the_error_envelope_and_the_session_lives_on(frame: str, code: str) -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        async with raw_client(emulator) as ws:
            await ws.send(frame)
            error = await next_of(ws, "error")
            assert error["error"]["code"] == code
            assert error["error"]["type"] == "invalid_request_error" and error["error"]["message"]
            await ws.send(MANUAL)
            updated = await next_of(ws, "session.updated")
            assert updated["session"]["audio"]["input"]["turn_detection"] is None

    run(body)


def test_binary_frames_are_refused() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        async with raw_client(emulator) as ws:
            await ws.send(b"\x00\x01")
            assert (await next_of(ws, "error"))["error"]["message"]

    run(body)


def test_truncate_beyond_the_audio_produced_is_the_real_servers_error() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        async with raw_client(emulator) as ws:
            await ws.send(json.dumps({"type": "response.create"}))
            received = 0
            while True:
                event = json.loads(await ws.recv())
                if event["type"] == "response.output_audio.delta":
                    received += len(base64.b64decode(event["delta"]))
                    item_id = event["item_id"]
                if event["type"] == "response.done":
                    break
            produced_ms = received // 48
            await ws.send(
                json.dumps(
                    {
                        "type": "conversation.item.truncate",
                        "item_id": item_id,
                        "content_index": 0,
                        "audio_end_ms": produced_ms + 85,
                    }
                )
            )
            error = await next_of(ws, "error")
            assert error["error"]["code"] == "invalid_value"
            assert error["error"]["message"] == (
                f"Audio content of {produced_ms} ms is already shorter than {produced_ms + 85} ms"
            )
            truncate = {"type": "conversation.item.truncate", "item_id": item_id, "content_index": 0}
            await ws.send(json.dumps({**truncate, "audio_end_ms": produced_ms}))
            assert (await next_of(ws, "conversation.item.truncated"))["audio_end_ms"] == produced_ms

    run(body, Script(turns=(Turn(Say("Short answer.")),)))


def test_beta_header_is_rejected_like_the_real_server() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        client = AsyncOpenAI(api_key="sk-test", websocket_base_url=emulator.websocket_base_url)
        async with client.beta.realtime.connect(model="gpt-4o-realtime-preview") as connection:
            event = await connection.recv()
            assert event.type == "error" and event.error.code == "beta_api_shape_disabled"
            with pytest.raises(ConnectionClosed) as closed:
                await connection.recv()
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 4000

    run(body)


@pytest.mark.parametrize("headers", [{"Authorization": "Bearer sk-revoked-0001"}, {}])
def test_bad_or_missing_key_fails_the_handshake_with_401(headers: dict[str, str]) -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        url = emulator.websocket_base_url + "/realtime?model=gpt-realtime-2.1"
        with pytest.raises(InvalidStatus) as refused:
            async with connect(url, additional_headers=headers):
                pass
        assert refused.value.response.status_code == 401
        assert json.loads(refused.value.response.body)["error"]["type"] == "invalid_request_error"

    run(body, Script(rejected_api_keys=("sk-revoked-0001",)))


def test_wrong_path_is_404() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        url = f"ws://127.0.0.1:{emulator.port}/v1/chat"
        with pytest.raises(InvalidStatus) as refused:
            async with connect(url, additional_headers={"Authorization": "Bearer sk-test"}):
                pass
        assert refused.value.response.status_code == 404

    run(body)


def test_received_records_every_event_with_its_connection_and_no_secret() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        for _ in range(2):
            async with raw_client(emulator) as ws:
                await ws.send(MANUAL)
                await next_of(ws, "session.updated")
        assert [(record.connection, record.event["type"]) for record in emulator.received] == [
            (0, "session.update"),
            (1, "session.update"),
        ]
        assert [handshake.model for handshake in emulator.handshakes] == ["gpt-realtime-2.1"] * 2
        assert all("authorization" not in handshake.headers for handshake in emulator.handshakes)

    run(body)


def test_binds_loopback_by_default() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        assert emulator.host == "127.0.0.1"
        assert emulator.base_url == f"http://127.0.0.1:{emulator.port}/v1"

    run(body)


def test_session_expiry_sends_session_expired_then_closes() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        async with raw_client(emulator) as ws:
            error = await next_of(ws, "error")
            assert error["error"]["code"] == "session_expired"
            with pytest.raises(ConnectionClosed):
                await ws.recv()

    run(body, Script(session_expiry_s=0.05))


def test_scripted_turns_are_consumed_across_connections_and_tool_calls_continue() -> None:
    async def body(emulator: OpenAIRealtimeEmulator) -> None:
        async with raw_client(emulator) as ws:
            await ws.send(
                json.dumps(
                    {"type": "session.update", "session": {"type": "realtime", "output_modalities": ["text"]}}
                )
            )
            await next_of(ws, "session.updated")
            await ws.send(json.dumps({"type": "response.create"}))
            assert (await next_of(ws, "response.output_text.done"))["text"] == "first"
        async with raw_client(emulator) as ws:
            await ws.send(json.dumps({"type": "response.create"}))
            call = await next_of(ws, "response.function_call_arguments.done")
            assert (call["name"], json.loads(call["arguments"])) == ("wave", {"arm": "left"})
            await next_of(ws, "response.done")
            output = {"type": "function_call_output", "call_id": call["call_id"], "output": "ok"}
            await ws.send(json.dumps({"type": "conversation.item.create", "item": output}))
            await ws.send(json.dumps({"type": "response.create"}))
            done = await next_of(ws, "response.output_audio_transcript.done")
            assert done["transcript"] == "Waved."

    script = Script(turns=(Turn(Say("first")), Turn(CallTool("wave", '{"arm": "left"}', Say("Waved.")))))
    run(body, script)
