"""The WebSocket server core over real loopback sockets, with a fake ROS graph, and our client."""

from __future__ import annotations

import asyncio
import gc
import json
import logging
import socket
import tracemalloc
import weakref
from collections.abc import Coroutine
from typing import Any

import pytest
import websockets
from bridge_fakes import NAMESPACE, eventually, make_core, masked_text_frame, raw_websocket, running_bridge
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from by_your_command.bridge.client import BridgeClient, BridgeRefused, ClientOptions
from by_your_command.bridge.config import BridgeParams
from by_your_command.bridge.core import BridgeCore, ClientSession
from by_your_command.bridge.server import BridgeServer

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


def run(coroutine: Coroutine[Any, Any, None]) -> None:
    asyncio.run(asyncio.wait_for(coroutine, 30))


def url(server: BridgeServer, query: str = "") -> str:
    return f"ws://127.0.0.1:{server.port}/{query}"


def test_client_subscribes_and_publishes_with_a_token(caplog: pytest.LogCaptureFixture) -> None:
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

    with caplog.at_level(logging.DEBUG):  # websockets logs handshake headers at DEBUG
        run(scenario())
    assert caplog.records and "s3cret" not in caplog.text  # neither side ever logs the token


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


def test_a_frame_of_multibyte_characters_is_refused_by_its_bytes_on_every_path() -> None:
    frame = '{"op":"publish","topic":"response_text","msg":{"data":"' + "€" * 600_000 + '"}}'
    size = len(frame.encode())  # 1.8 MB in 600,058 characters: over the limit, under the hard one

    async def scenario() -> None:
        async with running_bridge(inline_convert_bytes=1000) as (server, graph):
            held = "H" * 3000
            graph.hold(held)
            async with connect(url(server), compression=None) as client:
                await client.send(frame)
                replies = [json.loads(await client.recv())]
                await client.send(
                    json.dumps({"op": "publish", "topic": "response_text", "msg": {"data": held}})
                )
                await eventually(lambda: held in graph.converting, what="conversion running")
                await client.send(frame)  # while its previous frame is on a worker
                await client.send(frame.encode())  # the same bytes as a binary frame
                replies += [json.loads(await client.recv()) for _ in range(2)]
                graph.release(held)
                await eventually(lambda: graph.published, what="the held publish")
            assert [(r["code"], f"{size} bytes" in r["msg"]) for r in replies] == [("too_large", True)] * 3
            assert [msg["data"] for _, msg in graph.published] == [held]

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


def test_too_many_clients_are_refused() -> None:
    async def scenario() -> None:
        async with running_bridge(max_clients=1) as (server, _):
            async with connect(url(server)):
                await eventually(lambda: server.core.sessions, what="first client")
                with pytest.raises(InvalidStatus) as refused:
                    await websockets.connect(url(server))
                assert refused.value.response.status_code == 503

    run(scenario())


def test_foreign_browser_origins_are_refused_even_with_a_token() -> None:
    async def scenario() -> None:
        async with running_bridge(token="s3cret", allowed_origins=("https://Monitor.example:8443",)) as (
            server,
            _,
        ):
            bearer = {"Authorization": "Bearer s3cret"}
            for origin in ("http://evil.example", "null", f"http://127.0.0.1:{server.port + 1}"):
                with pytest.raises(InvalidStatus) as refused:
                    await connect(url(server), origin=origin, additional_headers=bearer)  # type: ignore[arg-type]
                assert refused.value.response.status_code == 403
            for origin in (f"http://localhost:{server.port}", f"http://127.0.0.1:{server.port}/"):
                async with connect(url(server), origin=origin, additional_headers=bearer):  # type: ignore[arg-type]
                    pass  # the bridge's own (monitor page) origins
            async with connect(url(server), origin="https://monitor.example:8443", additional_headers=bearer):  # type: ignore[arg-type]
                pass  # allow-listed
            async with connect(url(server), additional_headers=bearer):
                pass  # no Origin: not a browser (agents, roslibpy)
            with pytest.raises(InvalidStatus) as refused:
                await connect(url(server), origin=f"http://localhost:{server.port}")  # type: ignore[arg-type]
            assert refused.value.response.status_code == 401  # an allowed origin still needs the token
            assert server.refused_connections == 4

    run(scenario())


def test_foreign_origin_refused_on_loopback_without_token(caplog: pytest.LogCaptureFixture) -> None:
    async def scenario() -> None:
        async with running_bridge() as (server, _):
            with pytest.raises(InvalidStatus) as refused:
                await connect(url(server), origin="http://evil.example" + "x" * 5_000)  # type: ignore[arg-type]
            assert refused.value.response.status_code == 403
            assert not server.core.sessions

    with caplog.at_level("WARNING", logger="by_your_command.bridge.server"):
        run(scenario())
    [line] = [r.getMessage() for r in caplog.records if "origin" in r.getMessage()]
    assert "evil.example" in line and len(line) < 300


class LateHandlerServer(BridgeServer):
    """Handlers that start only when the test opens the gate: the window in which admission by
    counting open sessions let every concurrent handshake through."""

    def __init__(self, *args: Any) -> None:
        super().__init__(*args)
        self.gate = asyncio.Event()

    async def _handle(self, connection: Any) -> None:
        await self.gate.wait()
        await super()._handle(connection)


def test_concurrent_connects_never_exceed_max_clients() -> None:
    async def scenario() -> None:
        core, _ = make_core(BridgeParams(port=0, max_clients=3))
        server = LateHandlerServer(core, "")
        await server.start()
        try:

            async def attempt() -> Any:
                try:
                    return await connect(url(server), open_timeout=10)
                except InvalidStatus as error:
                    return error.response.status_code

            results = await asyncio.gather(*(attempt() for _ in range(30)))
            connections = [r for r in results if not isinstance(r, int)]
            assert len(connections) == 3 and {r for r in results if isinstance(r, int)} == {503}
            server.gate.set()
            await eventually(lambda: len(core.sessions) == 3, what="the admitted clients' sessions")
            for connection in connections:
                await connection.close()
            await eventually(lambda: server.admitted == 0 and not core.sessions, what="slots released")
            async with connect(url(server)):
                await eventually(lambda: core.sessions, what="a new client after the others left")
        finally:
            await server.stop()

    run(scenario())


def test_stop_ends_idle_and_half_open_connections_instead_of_waiting_for_them() -> None:
    """Browsers open TCP connections ahead of use; a request may never come on them. The stop
    must end them itself: the handshake timeout is ten minutes here."""

    async def scenario() -> None:
        core, _ = make_core(BridgeParams(port=0, handshake_timeout_s=600))
        server = BridgeServer(core, "")
        await server.start()
        loop = asyncio.get_running_loop()
        idle = socket.create_connection(("127.0.0.1", server.port))
        half_open = socket.create_connection(("127.0.0.1", server.port))
        half_open.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")  # the request never ends
        for sock in (idle, half_open):
            sock.setblocking(False)
        async with connect(url(server)) as client:
            await eventually(lambda: server.tcp_connections == 3, what="all three accepted")
            await server.stop()
            with pytest.raises(ConnectionClosed) as closed:
                await client.recv()
            assert closed.value.rcvd is not None and closed.value.rcvd.code == 1001  # going away
        for sock in (idle, half_open):
            try:
                assert await loop.sock_recv(sock, 1) == b""
            except ConnectionResetError:
                pass  # aborted: as closed as it gets
            sock.close()
        assert server.tcp_connections == 0

    run(scenario())


def test_hostile_numbers_get_a_status_error_not_a_closed_connection() -> None:
    async def scenario() -> None:
        async with running_bridge() as (server, _):
            async with connect(url(server), compression=None) as hostile:
                for frame in (
                    '{"op":"subscribe","id":1,"topic":"prompt_text","throttle_rate":NaN}',
                    '{"op":"subscribe","id":2,"topic":"prompt_text","queue_length":1e400}',
                    '{"op":"subscribe","id":3,"topic":"prompt_text","queue_length":' + "9" * 5000 + "}",
                    '{"op":"subscribe","id":4,"topic":"prompt_text","x":' + "[" * 5000 + "]" * 5000 + "}",
                ):
                    await hostile.send(frame)
                replies = [json.loads(await hostile.recv()) for _ in range(4)]
                # Refused while parsing, so their ids are unknown: the reply says why, without one.
                assert [(r["code"], r.get("id")) for r in replies] == [("bad_request", None)] * 4
                assert "NaN" in replies[0]["msg"] and "out of range" in replies[1]["msg"]
                await hostile.send('{"op":"subscribe","id":5,"topic":"nope"}')
                assert json.loads(await hostile.recv())["id"] == 5  # still connected, id still an integer

    run(scenario())


def test_a_client_that_never_reads_cannot_grow_the_bridge_with_refusals() -> None:
    async def scenario() -> None:
        async with running_bridge(rate_burst=100_000) as (server, _):
            tiny_window = socket.create_connection(("127.0.0.1", server.port))
            tiny_window.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # its replies back up at once
            async with connect(
                url(server), sock=tiny_window, compression=None, max_queue=1, close_timeout=0.2
            ) as silent:
                await eventually(lambda: server.core.sessions, what="session")
                session = server.core.sessions[0]
                [connection] = list(server._server.connections)  # type: ignore[union-attr]
                big_topic = json.dumps({"op": "subscribe", "topic": "a" * 200_000})

                async def flood() -> None:
                    for _ in range(200):
                        await silent.send(big_topic)  # blocks once the bridge stops reading from it

                flooding = asyncio.ensure_future(flood())
                await eventually(lambda: session.rejected >= 40, what="40 refusals", timeout=20)
                held = session.queue.queued_control_bytes + connection.transport.get_write_buffer_size()
                assert held <= 1000 * session.rejected  # a short reply each, never the 200 KB topic
                flooding.cancel()
                silent.transport.abort()  # it never reads: a polite close would wait for it

    run(scenario())


class TracedFrame(str):
    """A frame whose lifetime a test can watch (a str subclass takes weak references)."""


def without_cyclic_gc(test: Any) -> Any:
    """Memory held in a reference cycle is freed whenever the cyclic GC happens to run: off, a leak
    through a cycle is certain to show instead of now and then."""

    def wrapper() -> None:
        gc.disable()
        try:
            test()
        finally:
            gc.enable()

    wrapper.__name__ = test.__name__
    return wrapper


async def handle_and_wait_until_freed(core: BridgeCore, session: ClientSession, request: object) -> None:
    frame = TracedFrame(json.dumps(request))
    alive = weakref.ref(frame)
    core.handle_frame(session, frame)
    del frame
    await eventually(lambda: alive() is None, what=f"the frame of {str(request)[:40]} freed")


@without_cyclic_gc
def test_a_frame_converted_on_a_worker_is_freed_as_soon_as_it_is_handled() -> None:
    pad = "a" * 10_000

    async def scenario() -> None:
        core, graph = make_core(BridgeParams(port=0, inline_convert_bytes=100))  # every frame on a worker
        session = core.open_session("hostile")
        try:
            for request in (
                {"op": "subscribe", "topic": pad},  # refused by the parser
                {"op": "publish", "topic": "response_text", "msg": {"data": 7, "pad": pad}},  # by conversion
                {"op": "subscribe", "topic": "no_such_topic", "pad": pad},  # by the allow-list
                {"op": "publish", "topic": "response_text", "msg": {"data": pad}},  # published
            ):
                await handle_and_wait_until_freed(core, session, request)
            assert session.rejected == 3 and len(graph.published) == 1
        finally:
            core.shutdown()

    run(scenario())


@without_cyclic_gc
def test_a_client_that_never_reads_cannot_grow_the_bridge_with_large_refused_requests() -> None:
    size = 1_000_000  # 80 of these, refused, held 50 MB in the bridge
    params = {"rate_burst": 100_000, "pending_publish_bytes": 2 * size}

    async def scenario() -> None:
        async with running_bridge(**params) as (server, _):
            loop = asyncio.get_running_loop()
            silent = await loop.run_in_executor(None, raw_websocket, server.port)
            await eventually(lambda: server.core.sessions, what="session")
            session = server.core.sessions[0]
            frame = masked_text_frame(json.dumps({"op": "subscribe", "topic": "a" * size}))

            def flood() -> None:
                for _ in range(80):
                    silent.sendall(frame)

            tracemalloc.start()
            try:
                flooding = loop.run_in_executor(None, flood)
                await eventually(lambda: session.rejected == 80, timeout=30, what="80 refusals")
                _, peak = tracemalloc.get_traced_memory()
            finally:
                tracemalloc.stop()
                silent.close()
            await flooding
            # Frames waiting behind the one on a worker, that one and its parsed copy, the few
            # websockets reads ahead, copies while decoding: about 9 frames' worth. Not every
            # refused frame until the cyclic GC runs (all 80 here).
            assert peak < params["pending_publish_bytes"] + 11 * size, peak

    run(scenario())


def test_a_paused_client_costs_its_pending_bound_and_a_few_frames_not_sixteen() -> None:
    size = 1_000_000
    params = {"inline_convert_bytes": 1000, "pending_publish_bytes": 2 * size}

    async def scenario() -> None:
        async with running_bridge(**params) as (server, graph):
            loop = asyncio.get_running_loop()
            pusher = await loop.run_in_executor(None, raw_websocket, server.port)
            await eventually(lambda: server.core.sessions, what="session")
            session = server.core.sessions[0]
            [connection] = list(server._server.connections)  # type: ignore[union-attr]
            held = "H" * size
            graph.hold(held)
            first = masked_text_frame(
                json.dumps({"op": "publish", "topic": "response_text", "msg": {"data": held}})
            )
            frame = masked_text_frame(
                json.dumps({"op": "publish", "topic": "response_text", "msg": {"data": "h" * size}})
            )

            def push() -> None:
                try:
                    pusher.sendall(first)
                    for _ in range(40):
                        pusher.sendall(frame)  # blocks once the bridge stops reading
                except OSError:
                    pass  # closed by the test

            tracemalloc.start()
            try:
                pushing = loop.run_in_executor(None, push)
                await eventually(lambda: not server.core.accepts_more(session), what="reading paused")
                await eventually(lambda: not connection.transport.is_reading(), what="socket not read")
                held_bytes, _ = tracemalloc.get_traced_memory()
            finally:
                tracemalloc.stop()
                graph.release(held)
                pusher.close()
            await pushing
            # Its waiting frames, the one converting and its parsed copy, the few frames websockets
            # reads ahead, copies while decoding: about 9 frames' worth. websockets' default
            # read-ahead alone is 16 frames (of up to 4x max_message_bytes each).
            assert held_bytes < params["pending_publish_bytes"] + 11 * size, held_bytes

    run(scenario())


def test_a_heavy_conversion_does_not_block_other_clients_and_order_is_kept() -> None:
    heavy = "H" * 3000  # above inline_convert_bytes: converted on a worker thread

    async def scenario() -> None:
        async with running_bridge(inline_convert_bytes=1000) as (server, graph):
            graph.hold(heavy)
            async with connect(url(server)) as slowpoke, connect(url(server)) as speaker:
                await slowpoke.send(
                    json.dumps({"op": "publish", "topic": "response_text", "msg": {"data": heavy}})
                )
                await slowpoke.send('{"op":"publish","topic":"response_text","msg":{"data":"after heavy"}}')
                await eventually(lambda: heavy in graph.converting, what="heavy conversion running")
                await speaker.send('{"op":"publish","topic":"response_cmd","msg":{"data":"light"}}')
                await eventually(lambda: graph.published, what="light publish while heavy converts")
                assert graph.published == [(f"{NAMESPACE}/response_cmd", {"data": "light"})]
                assert heavy in graph.converting  # still held: the light one did not wait for it
                graph.release(heavy)
                await eventually(lambda: len(graph.published) == 3, what="heavy client's publishes")
                assert [msg["data"] for _, msg in graph.published[1:]] == [heavy, "after heavy"]

    run(scenario())


def test_a_heavy_client_is_paused_not_buffered_while_its_conversion_runs() -> None:
    heavy = "H" * 3000

    async def scenario() -> None:
        async with running_bridge(inline_convert_bytes=1000, pending_publish_messages=4) as (server, graph):
            graph.hold(heavy)
            async with connect(url(server)) as pusher:
                await pusher.send(
                    json.dumps({"op": "publish", "topic": "response_text", "msg": {"data": heavy}})
                )
                await eventually(lambda: heavy in graph.converting, what="heavy conversion running")
                session = server.core.sessions[0]
                sends = [
                    asyncio.ensure_future(
                        pusher.send(
                            json.dumps({"op": "publish", "topic": "response_text", "msg": {"data": str(i)}})
                        )
                    )
                    for i in range(40)
                ]
                await eventually(lambda: len(session.pending) == 4, what="bound reached")
                assert not server.core.accepts_more(session) and session.received == 5  # reading paused
                graph.release(heavy)
                await asyncio.gather(*sends)
                await eventually(lambda: len(graph.published) == 41, what="everything published in order")
                assert [msg["data"] for _, msg in graph.published] == [heavy] + [str(i) for i in range(40)]

    run(scenario())
