"""The WebSocket server core over real loopback sockets, with a fake ROS graph, and our client."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Coroutine
from typing import Any

import pytest
import websockets
from bridge_fakes import NAMESPACE, eventually, make_core, running_bridge
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from by_your_command.bridge.client import BridgeClient, BridgeRefused, BridgeUnavailable, ClientOptions
from by_your_command.bridge.config import BridgeParams
from by_your_command.bridge.server import BridgeServer

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


def run(coroutine: Coroutine[Any, Any, None]) -> None:
    asyncio.run(asyncio.wait_for(coroutine, 30))


def url(server: BridgeServer, query: str = "") -> str:
    return f"ws://127.0.0.1:{server.port}/{query}"


def test_client_subscribes_and_publishes_with_a_token() -> None:
    async def scenario() -> None:
        async with running_bridge(token="s3cret") as (server, graph):
            async with BridgeClient(url(server), ClientOptions(token="s3cret")) as client:
                await client.wait_connected(5)
                await client.subscribe("prompt_text", "std_msgs/String")
                await eventually(lambda: graph.subscribed == {f"{NAMESPACE}/prompt_text"}, what="subscribe")
                server.core.deliver(f"{NAMESPACE}/prompt_text", '{"data":"hello"}')
                incoming = await client.receive(5)
                assert (incoming.topic, incoming.msg) == ("prompt_text", {"data": "hello"})
                await client.advertise("response_text", "std_msgs/msg/String")
                await client.publish("response_text", {"data": "hi robot"})
                await eventually(lambda: graph.published, what="publish")
                assert graph.published == [(f"{NAMESPACE}/response_text", {"data": "hi robot"})]

    run(scenario())


def test_unauthorized_clients_are_refused() -> None:
    async def scenario() -> None:
        async with running_bridge(token="s3cret") as (server, _):
            for presented in ("", "wrong"):
                client = BridgeClient(url(server), ClientOptions(token=presented))
                await client.start()
                with pytest.raises(BridgeRefused, match="401"):
                    await client.wait_connected(5)
                await client.close()
            with pytest.raises(InvalidStatus) as refused:
                await connect(url(server, "?token=nope"))
            assert refused.value.response.status_code == 401
            async with connect(url(server, "?token=s3cret")) as browser_style:  # roslib.js cannot set headers
                await browser_style.send('{"op":"subscribe","topic":"prompt_text"}')
                await eventually(lambda: server.core.subscribed_topics(), what="subscription")
            assert server.refused_connections == 3

    run(scenario())


def test_bad_clients_get_errors_and_others_keep_being_served() -> None:
    async def scenario() -> None:
        async with running_bridge(max_message_bytes=1000) as (server, graph):
            async with BridgeClient(url(server)) as good, connect(url(server), compression=None) as bad:
                await good.wait_connected(5)
                await good.subscribe("prompt_text")
                await eventually(lambda: graph.subscribed, what="good subscription")
                requests = [
                    "{malformed",
                    '{"op":"fly"}',
                    '{"op":"subscribe","topic":"prompt_text","type":"std_msgs/Int8"}',
                    '{"op":"subscribe","topic":"no_such_topic"}',
                    '{"op":"publish","topic":"prompt_voice","msg":{}}',
                    '{"op":"publish","topic":"response_text","msg":{"data":[1]}}',
                    "x" * 2000,  # over the protocol limit: an error, the connection stays
                ]
                for request in requests:
                    await bad.send(request)
                replies = [json.loads(await bad.recv()) for _ in requests]
                assert [r["op"] for r in replies] == ["status"] * len(requests)
                assert [r["code"] for r in replies] == [
                    "bad_request",
                    "bad_request",
                    "wrong_type",
                    "not_allowed",
                    "not_allowed",
                    "bad_message",
                    "too_large",
                ]
                server.core.deliver(f"{NAMESPACE}/prompt_text", '{"data":"still here"}')
                assert (await good.receive(5)).msg == {"data": "still here"}
                await bad.send("y" * 5000)  # beyond the hard limit: the bad client is cut off
                with pytest.raises(ConnectionClosed) as closed:
                    await bad.recv()
                assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009
                server.core.deliver(f"{NAMESPACE}/prompt_text", '{"data":"and here"}')
                assert (await good.receive(5)).msg == {"data": "and here"}
                assert graph.published == []

    run(scenario())


def test_a_slow_client_neither_stalls_others_nor_grows_memory() -> None:
    frame = json.dumps({"data": "z" * 20_000})
    sent = 400

    async def scenario() -> None:
        async with running_bridge(send_queue_messages=32, send_queue_bytes=400_000) as (server, _):
            async with (
                BridgeClient(url(server), ClientOptions(receive_queue=sent)) as fast,
                connect(url(server), compression=None, max_queue=1, close_timeout=0.2) as slow,
            ):
                await fast.wait_connected(5)
                await fast.subscribe("prompt_text")
                await slow.send('{"op":"subscribe","topic":"prompt_voice"}')
                await slow.send('{"op":"subscribe","topic":"camera_forwarded"}')
                await eventually(lambda: len(server.core.subscribed_topics()) == 3, what="subscriptions")
                slow_session = next(s for s in server.core.sessions if "prompt_voice" in str(s.subscriptions))
                peak = 0
                for _ in range(sent):
                    server.core.deliver(f"{NAMESPACE}/prompt_voice", frame)
                    server.core.deliver(f"{NAMESPACE}/camera_forwarded", frame)
                    server.core.deliver(f"{NAMESPACE}/prompt_text", '{"data":"x"}')
                    peak = max(peak, slow_session.queue.queued_bytes)
                    await asyncio.sleep(0)  # let the socket tasks run between deliveries
                received = 0
                while received < sent:
                    await fast.receive(5)
                    received += 1
                assert peak <= 400_000
                dropped = slow_session.queue.dropped
                assert (
                    dropped[f"{NAMESPACE}/prompt_voice"] > 0 and dropped[f"{NAMESPACE}/camera_forwarded"] > 0
                )
                # The slow client finally reads: it is told how much audio it lost (video is drop-oldest).
                reports = []
                while not reports:
                    item = json.loads(await asyncio.wait_for(slow.recv(), 5))
                    if item["op"] == "status":
                        reports.append(item)
                assert reports[0]["code"] == "dropped"
                assert set(reports[0]["counts"]) == {f"{NAMESPACE}/prompt_voice"}

    run(scenario())


def test_client_reconnects_and_resubscribes() -> None:
    async def scenario() -> None:
        core, graph = make_core(BridgeParams(port=0))
        server = BridgeServer(core, "")
        await server.start()
        port = server.port
        client = BridgeClient(
            f"ws://127.0.0.1:{port}/", ClientOptions(backoff_initial_s=0.05, backoff_max_s=0.2)
        )
        await client.start()
        await client.wait_connected(5)
        await client.subscribe("prompt_text")
        await client.advertise("response_text", "std_msgs/String")
        await eventually(lambda: graph.subscribed, what="first subscription")
        await server.stop()
        await eventually(lambda: not client.connected, what="disconnect noticed")
        with pytest.raises(BridgeUnavailable):
            await client.publish("response_text", {"data": "lost"})
        core2, graph2 = make_core(BridgeParams(port=port))
        server2 = BridgeServer(core2, "")
        await server2.start()
        try:
            await client.wait_connected(5)
            await eventually(lambda: graph2.subscribed and graph2.advertised, what="replayed requests")
            core2.deliver(f"{NAMESPACE}/prompt_text", '{"data":"back"}')
            assert (await client.receive(5)).msg == {"data": "back"}
            assert client.connects == 2
        finally:
            await client.close()
            await server2.stop()

    run(scenario())


def test_client_receive_queue_is_bounded() -> None:
    async def scenario() -> None:
        async with running_bridge() as (server, graph):
            async with BridgeClient(url(server), ClientOptions(receive_queue=5)) as client:
                await client.wait_connected(5)
                await client.subscribe("prompt_text")
                await eventually(lambda: graph.subscribed, what="subscription")
                for index in range(20):
                    server.core.deliver(f"{NAMESPACE}/prompt_text", f'{{"data":"{index}"}}')
                await eventually(lambda: client.dropped == 15, what="15 drops")
                assert [(await client.receive(1)).msg["data"] for _ in range(5)] == [
                    "15",
                    "16",
                    "17",
                    "18",
                    "19",
                ]

    run(scenario())


def test_too_many_clients_are_refused() -> None:
    async def scenario() -> None:
        async with running_bridge(max_clients=1) as (server, _):
            async with connect(url(server)):
                await eventually(lambda: server.core.sessions, what="first client")
                with pytest.raises(InvalidStatus) as refused:
                    await websockets.connect(url(server))
                assert refused.value.response.status_code == 503

    run(scenario())
