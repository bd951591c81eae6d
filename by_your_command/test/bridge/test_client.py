"""BridgeClient (the agents' side) over real loopback WebSockets.

Most tests talk to a scripted rosbridge server whose frames the test writes by hand, so it can be
as hostile as needed; the loss-report test runs the real bridge core and server (fake ROS graph).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
from collections.abc import Coroutine
from dataclasses import replace
from http import HTTPStatus
from typing import Any

import pytest
from bridge_fakes import NAMESPACE, eventually, make_core
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

import by_your_command.bridge.client as client_module
from by_your_command.bridge.calls import CallOutcome
from by_your_command.bridge.client import (
    BridgeClient,
    BridgeRefused,
    BridgeUnavailable,
    ClientClosed,
    ClientFailed,
    ClientOptions,
    GoalFeedback,
    GoalResult,
    Lost,
    Received,
    ServiceReply,
    TooManyCalls,
)
from by_your_command.bridge.client_inbox import Inbox, InboxLimits
from by_your_command.bridge.config import BridgeParams, parse_allow_lists
from by_your_command.bridge.protocol import Status
from by_your_command.bridge.server import BridgeServer

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

FAST = ClientOptions(backoff_initial_s=0.02, backoff_max_s=0.1)


def run(coroutine: Coroutine[Any, Any, None]) -> None:
    asyncio.run(asyncio.wait_for(coroutine, 30))


def publish(topic: str, msg: dict[str, Any]) -> str:
    return json.dumps({"op": "publish", "topic": topic, "msg": msg})


def chunk(sequence: int, end: bool = False) -> dict[str, Any]:
    return {"int16_data": [sequence] * 4, "chunk_sequence": sequence, "is_utterance_end": end}


def playback(stream_id: str, played_ms: int, finished: bool = False) -> dict[str, Any]:
    return {"stream_id": stream_id, "played_ms": played_ms, "speaking": not finished, "finished": finished}


class ScriptedBridge:
    """A WebSocket server speaking rosbridge frames the test writes; records every request."""

    def __init__(self) -> None:
        self.connections: list[ServerConnection] = []
        self.requests: list[list[dict[str, Any]]] = []  # per connection, in order
        self.refuse_with: HTTPStatus | None = None
        self._server: Server | None = None
        self.port = 0

    async def start(self) -> None:
        self._server = await serve(
            self._handle, "127.0.0.1", self.port, compression=None, process_request=self._gate
        )
        self.port = self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        assert self._server is not None
        self._server.close()
        await self._server.wait_closed()

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/"

    def _gate(self, connection: ServerConnection, request: Request) -> Response | None:
        if self.refuse_with is not None:
            return connection.respond(self.refuse_with, "refused\n")
        return None

    async def _handle(self, connection: ServerConnection) -> None:
        requests: list[dict[str, Any]] = []
        self.connections.append(connection)
        self.requests.append(requests)
        with contextlib.suppress(ConnectionClosed):
            async for frame in connection:
                requests.append(json.loads(frame))

    def ops(self, connection: int = -1) -> list[tuple[str, str]]:
        return [(r["op"], r["topic"]) for r in self.requests[connection]]

    async def send(self, *frames: str) -> None:
        for frame in frames:
            await self.connections[-1].send(frame)


async def scripted() -> ScriptedBridge:
    bridge = ScriptedBridge()
    await bridge.start()
    return bridge


async def connected_client(
    bridge: ScriptedBridge, *topics: str, options: ClientOptions = FAST, **kwargs: Any
) -> BridgeClient:
    client = BridgeClient(bridge.url, options, **kwargs)
    await client.start()
    await client.wait_connected(5)
    for topic in topics:
        await client.subscribe(topic)
    await eventually(lambda: len(bridge.requests[-1]) == len(topics), what="subscriptions")
    return client


async def receive_all(client: BridgeClient, count: int) -> list[Received | Lost]:
    return [await client.receive(5) for _ in range(count)]


# --- 1. nothing the bridge or a callback does ends the client ------------------------------------


def test_the_token_never_reaches_the_logs_even_at_debug(caplog: pytest.LogCaptureFixture) -> None:
    token = "tok-3f9a1c77e0"  # noqa: S105 - a recognisable fake

    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "prompt_text", options=ClientOptions(token=token))
        try:
            await bridge.send(publish("prompt_text", {"data": "hi"}))
            assert isinstance(await client.receive(5), Received)
        finally:
            await client.close()
            await bridge.stop()

    with caplog.at_level(logging.DEBUG):
        run(scenario())
    # the scripted server in this test is the stock websockets one: only the client's side counts.
    # Each record as a handler writes it: the message, and any traceback or stack it carries.
    full = logging.Formatter("%(name)s %(levelname)s %(message)s")
    client_side = [full.format(r) for r in caplog.records if not r.name.startswith("websockets.server")]
    assert any("connected" in line for line in client_side)
    assert not [line for line in client_side if token in line]


def test_a_raising_status_callback_is_contained_and_counted() -> None:
    def on_status(status: Status) -> None:
        raise RuntimeError(f"agent bug on {status.code}")

    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "prompt_text", on_status=on_status)
        try:
            await bridge.send(
                json.dumps({"op": "status", "level": "warning", "msg": "x", "code": "dropped", "counts": {}}),
                publish("prompt_text", {"data": "still listening"}),
            )
            delivery = await client.receive(5)
            assert isinstance(delivery, Received) and delivery.msg == {"data": "still listening"}
            health = client.health()
            assert (health.callback_errors, health.connected, health.connects) == (1, True, 1)
            assert "agent bug" in health.last_error
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_malformed_frames_and_odd_status_fields_are_counted_and_skipped() -> None:
    hostile = [
        "{not json",
        "[1, 2]",
        "[" * 100_000,  # nesting deeper than the JSON parser recurses
        '{"op":"fly"}',
        '{"op":"publish","topic":"prompt_text"}',
        '{"op":"publish","topic":7,"msg":{}}',
        '{"op":"publish","topic":"prompt_text","msg":[1]}',
    ]
    odd_status = {
        "op": "status",
        "level": "panic",
        "msg": {"nested": True},
        "code": "dropped",
        "counts": {"/robot1/prompt_text": "many", f"{NAMESPACE}/prompt_voice": 2, "/c": 1e400, "/d": -1},
    }

    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "prompt_text", "prompt_voice")
        try:
            await bridge.send(*hostile, json.dumps(odd_status))  # 1e400 is sent as Infinity
            await bridge.send(publish("prompt_text", {"data": "after the garbage"}))
            lost = await client.receive(5)  # the usable part of the odd report: 2 audio lost
            assert isinstance(lost, Lost) and (lost.topic, lost.topic_class, lost.count) == (
                "prompt_voice",
                "audio",
                2,
            )
            delivery = await client.receive(5)
            assert isinstance(delivery, Received) and delivery.msg == {"data": "after the garbage"}
            health = client.health()
            assert health.protocol_errors == len(hostile) + 1
            assert health.connects == 1 and health.connected  # no reconnect needed
            assert client.statuses[-1].level == "error"  # an unknown level is not reassuring
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_losses_before_the_bridge_are_delivered_as_lost_with_their_reason() -> None:
    # The bridge reports ROS-side losses (history overwritten before it read them) as `lost`.
    report = {"op": "status", "level": "warning", "msg": "x", "code": "lost", "counts": {"prompt_voice": 3}}

    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "prompt_voice")
        try:
            await bridge.send(publish("prompt_voice", chunk(0)), json.dumps(report))
            await bridge.send(publish("prompt_voice", chunk(4, end=True)))
            first, lost, last = await receive_all(client, 3)
            assert isinstance(first, Received) and isinstance(last, Received)
            assert isinstance(lost, Lost) and (lost.topic, lost.count) == ("prompt_voice", 3)
            assert "before the bridge" in lost.reason
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_an_unexpected_error_in_the_connection_loop_does_not_stop_reconnecting(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "prompt_text")
        real_encode = client_module.encode_request
        failures = iter([RuntimeError("surprise 1"), ValueError("surprise 2")])

        def flaky_encode(request: Any) -> str:
            error = next(failures, None)
            if error is not None:
                raise error
            return real_encode(request)

        monkeypatch.setattr(client_module, "encode_request", flaky_encode)
        try:
            await bridge.connections[-1].close()  # the bridge restarts: the replay hits two bugs
            await eventually(lambda: len(bridge.connections) == 4, what="three reconnects")
            await eventually(lambda: bridge.ops() == [("subscribe", "prompt_text")], what="replay")
            await bridge.send(publish("prompt_text", {"data": "back"}))
            deliveries = await receive_all(client, 2)
            assert isinstance(deliveries[0], Lost) and deliveries[0].count is None
            assert isinstance(deliveries[1], Received) and deliveries[1].msg == {"data": "back"}
            health = client.health()
            assert (health.internal_errors, health.connects, health.reconnects) == (2, 2, 1)
            assert "surprise 2" in health.last_error
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


@pytest.mark.parametrize(
    ("stable_after_s", "attempts"),
    [(5.0, [2, 3, 4]), (0.0, [1, 1, 1])],  # quick failures climb; a loss after a stable link starts over
)
def test_reconnect_waits_come_from_the_shared_backoff_with_the_options(
    monkeypatch: pytest.MonkeyPatch, stable_after_s: float, attempts: list[int]
) -> None:
    """The delays themselves are net/backoff.py's (test/net/test_backoff.py); here: what it is asked."""
    asked: list[tuple[int, float, float]] = []

    def recorded(attempt: int, initial_s: float, max_s: float, uniform: Any) -> float:
        asked.append((attempt, initial_s, max_s))
        return 0.0

    monkeypatch.setattr(client_module, "backoff_s", recorded)

    async def scenario() -> None:
        bridge = await scripted()
        await bridge.stop()  # nothing listens: every connect fails at once
        options = ClientOptions(backoff_initial_s=0.3, backoff_max_s=7.0, stable_after_s=stable_after_s)
        client = BridgeClient(bridge.url, options)
        await client.start()
        try:
            await eventually(lambda: len(asked) >= 3, what="three failed connects")
        finally:
            await client.close()

    run(scenario())
    assert asked[:3] == [(attempt, 0.3, 7.0) for attempt in attempts]


# --- receive() reports a dead client -----------------------------------------------------------


def test_receive_raises_once_the_client_is_closed_after_draining() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "prompt_text")
        await bridge.send(publish("prompt_text", {"data": "last words"}))
        await eventually(lambda: client.health().queued["text"] == 1, what="message buffered")
        waiter = asyncio.ensure_future(client.receive())
        assert isinstance(await waiter, Received)
        waiter = asyncio.ensure_future(client.receive())  # nothing left: waits...
        await asyncio.sleep(0)  # (a yield, not a delay: the waiter reaches its wait)
        await client.close()
        with pytest.raises(ClientClosed):  # ...and is woken, not left waiting forever
            await asyncio.wait_for(waiter, 5)
        with pytest.raises(ClientClosed):
            client.receive_nowait()
        with pytest.raises(ClientClosed):
            await client.publish("response_text", {"data": "too late"})
        assert not client.health().running
        await bridge.stop()

    run(scenario())


def test_receive_raises_when_the_bridge_refuses_the_token() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        bridge.refuse_with = HTTPStatus.UNAUTHORIZED
        client = BridgeClient(bridge.url, ClientOptions(token="wrong"))
        await client.start()
        try:
            with pytest.raises(BridgeRefused, match="401"):
                await asyncio.wait_for(client.receive(), 5)
            with pytest.raises(BridgeRefused):
                await client.wait_connected(5)
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_receive_raises_when_the_supervisor_task_dies() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "voice_activity")
        waiter = asyncio.ensure_future(client.receive())
        supervisor = next(t for t in asyncio.all_tasks() if t.get_name() == f"bridge-client {bridge.url}")
        supervisor.cancel()  # what no exception inside it can do any more
        with pytest.raises(ClientFailed, match="supervisor"):
            await asyncio.wait_for(waiter, 5)
        assert not client.health().running
        await client.close()
        await bridge.stop()

    run(scenario())


# --- 2. per-class lanes ------------------------------------------------------------------------


def test_commands_then_state_then_audio_whatever_the_arrival_order() -> None:
    topics = ("prompt_voice", "voice_activity", "playback_status", "command_status", "camera_forwarded")

    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, *topics)
        try:
            frames = [publish("prompt_voice", chunk(i)) for i in range(50)]
            frames += [
                publish("voice_activity", {"data": True}),
                publish("playback_status", playback("reply-1", 800)),
                publish("camera_forwarded", {"format": "jpeg", "data": "frame-1"}),
                publish("playback_status", playback("reply-1", 1200, finished=True)),
                publish("playback_status", playback("reply-1", 1200)),  # a late echo: must not win
                publish("playback_status", playback("reply-2", 100)),
                publish("prompt_voice", chunk(50, end=True)),
                publish("camera_forwarded", {"format": "jpeg", "data": "frame-2"}),
                publish("command_status", {"raw": "stop", "accepted": True}),
                publish("voice_activity", {"data": False}),
            ]
            await bridge.send(*frames)
            await eventually(lambda: sum(client.health().queued.values()) == 56, what="all frames read")
            out = await receive_all(client, 56)
            assert all(isinstance(d, Received) for d in out)
            received = [d for d in out if isinstance(d, Received)]
            summary = [(d.topic, d.msg.get("stream_id", d.msg.get("data"))) for d in received[:4]]
            assert summary == [
                ("command_status", None),
                ("playback_status", "reply-1"),
                ("playback_status", "reply-2"),
                ("voice_activity", False),
            ]
            reply_1, voice = received[1], received[3]
            assert reply_1.msg["finished"] and reply_1.superseded == 2
            assert voice.superseded == 1  # the agent learns a True came and went unseen
            data = [(d.topic, d.msg.get("chunk_sequence", d.msg.get("data"))) for d in received[4:]]
            assert data == [("prompt_voice", i) for i in range(51)] + [("camera_forwarded", "frame-2")]
            assert [d.topic_class for d in received[:5]] == ["command", "state", "state", "state", "audio"]
            health = client.health()
            assert health.dropped == {"audio": 0, "video": 1, "command": 0, "state": 3, "text": 0}
            assert sum(health.queued.values()) == 0
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_audio_is_never_dropped_a_full_lane_stops_reading_instead() -> None:
    sent = 3000

    async def scenario() -> None:
        bridge = await scripted()
        options = ClientOptions(receive_queue=10, backoff_initial_s=0.02, backoff_max_s=0.1)
        client = await connected_client(bridge, "prompt_voice", "voice_activity", options=options)
        try:
            frames = [publish("prompt_voice", chunk(i, end=i == sent - 1)) for i in range(sent)]
            sender = asyncio.ensure_future(bridge.send(*frames))
            await eventually(lambda: client.health().reading_paused, what="reading paused")
            assert client.health().queued["audio"] == 10  # bounded: the rest waits in the socket
            out = await receive_all(client, sent)
            await sender
            assert [d.msg["chunk_sequence"] for d in out if isinstance(d, Received)] == list(range(sent))
            assert isinstance(out[-1], Received) and out[-1].msg["is_utterance_end"]
            health = client.health()
            assert health.dropped["audio"] == 0 and health.reading_pauses > 0
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_losses_the_real_bridge_reports_come_out_in_order_as_lost() -> None:
    """A client that stops reading: the real bridge drops and reports, the agent sees `Lost`."""
    sent = 400
    padding = "z" * 100_000  # 40 MB in all: more than the kernel buffers between the two

    async def scenario() -> None:
        allow = parse_allow_lists(
            {"subscribe": [{"topic": "prompt_voice", "type": "by_your_command_msgs/msg/AudioDataUtterance"}]}
        )
        core, graph = make_core(BridgeParams(port=0, send_queue_messages=16), allow)
        server = BridgeServer(core, "")
        await server.start()
        options = ClientOptions(receive_queue=20)
        async with BridgeClient(f"ws://127.0.0.1:{server.port}/", options) as client:
            try:
                await client.wait_connected(5)
                await client.subscribe("prompt_voice")
                await eventually(lambda: graph.subscribed, what="subscription")
                for index in range(sent):
                    msg = {"chunk_sequence": index, "is_utterance_end": index == sent - 1, "pad": padding}
                    core.deliver(f"{NAMESPACE}/prompt_voice", json.dumps(msg))
                    await asyncio.sleep(0)  # let the bridge's writer and our reader run
                received: list[int] = []
                lost = 0
                while len(received) + lost < sent:
                    delivery = await client.receive(10)
                    if isinstance(delivery, Lost):
                        assert (delivery.topic, delivery.topic_class) == ("prompt_voice", "audio")
                        assert delivery.count is not None
                        lost += delivery.count
                    else:
                        received.append(delivery.msg["chunk_sequence"])
                assert lost > 0 and received == sorted(received)
                health = client.health()
                assert health.bridge_dropped["audio"] == lost and health.dropped["audio"] == 0
            finally:
                await server.stop()

    run(scenario())


def test_a_lost_connection_is_reported_to_the_consumer_in_order() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "prompt_voice", "voice_activity", "command_status")
        try:
            await bridge.send(publish("prompt_voice", chunk(0)), publish("voice_activity", {"data": True}))
            await eventually(lambda: sum(client.health().queued.values()) == 2, what="frames read")
            await bridge.connections[-1].close(1011)  # mid-utterance: the end marker will never come
            await eventually(lambda: len(bridge.connections) == 2 and client.connected, what="reconnect")
            out = await receive_all(client, 4)
            kinds = [(type(d).__name__, d.topic) for d in out]
            assert kinds == [
                ("Lost", "command_status"),
                ("Received", "voice_activity"),  # state is replayed by the bridge: no loss event
                ("Received", "prompt_voice"),
                ("Lost", "prompt_voice"),
            ]
            assert all(d.count is None for d in out if isinstance(d, Lost))
            assert client.health().unknown_losses == 2
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


# --- 3. publishing -----------------------------------------------------------------------------


def test_publish_fails_loudly_when_disconnected_and_readvertises_on_reconnect() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "command_status")
        try:
            await client.advertise("response_cmd", "std_msgs/String")
            await client.publish("response_cmd", {"data": "stop"}, request_id="cmd-1")
            await eventually(lambda: len(bridge.requests[0]) == 3, what="advertise and publish")
            assert bridge.requests[0][2] == {
                "op": "publish",
                "topic": "response_cmd",
                "msg": {"data": "stop"},
                "id": "cmd-1",
            }
            with pytest.raises(ValueError):  # JSON has no NaN: refused here, not by the bridge later
                await client.publish("response_cmd", {"data": math.nan})
            await bridge.stop()
            await eventually(lambda: not client.connected, what="disconnect noticed")
            with pytest.raises(BridgeUnavailable, match="not connected"):
                await client.publish("response_cmd", {"data": "reach"})
            await bridge.start()  # same port
            await client.wait_connected(5)
            await client.publish("response_cmd", {"data": "wave"})
            await eventually(lambda: len(bridge.requests[-1]) == 3, what="replay and publish")
            assert bridge.ops() == [
                ("advertise", "response_cmd"),
                ("subscribe", "command_status"),
                ("publish", "response_cmd"),
            ]
            assert bridge.requests[-1][2]["msg"] == {"data": "wave"}
            assert all(
                r["msg"] != {"data": "reach"} for c in bridge.requests for r in c if r["op"] == "publish"
            )
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_receive_on_a_client_never_started_says_so() -> None:
    async def scenario() -> None:
        with pytest.raises(BridgeUnavailable, match="not started"):
            await BridgeClient("ws://127.0.0.1:9/").receive(5)

    run(scenario())


def test_state_losses_merge_and_pending_keys_are_bounded() -> None:
    inbox = Inbox(InboxLimits(state_keys_per_topic=2))
    for stream_id in ("a", "b", "c"):  # three replies pending for a bound of two: the oldest goes
        inbox.put(Received("playback_status", "state", playback(stream_id, 10), 0.0))
    inbox.put_lost(Lost("voice_activity", "state", 2, "bridge", 0.0))
    inbox.put_lost(Lost("voice_activity", "state", None, "reconnect", 0.0))
    out = [inbox.pop() for _ in range(len(inbox))]
    assert [d.msg["stream_id"] for d in out if isinstance(d, Received)] == ["b", "c"]
    losses = [d for d in out if isinstance(d, Lost)]
    assert len(losses) == 1 and losses[0].count is None  # 2 + unknown = unknown
    assert inbox.dropped["state"] == 1 and inbox.pop() is None and inbox.queued()["state"] == 0


# --- 4. service calls and action goals (issue 35) -------------------------------------------------


def service_response(request_id: Any, values: Any, result: bool = True, **extra: Any) -> str:
    frame = {
        "op": "service_response",
        "service": "/reset",
        "id": request_id,
        "values": values,
        "result": result,
    }
    return json.dumps({**frame, **extra})


def action_frame(op: str, request_id: Any, values: Any, **extra: Any) -> str:
    return json.dumps({"op": op, "action": "/nav", "id": request_id, "values": values, **extra})


def test_calls_are_sent_as_rosbridge_ops_and_replies_come_out_first() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, "prompt_text")
        try:
            await client.call_service("/reset", {"hard": True}, "c1", "std_srvs/Trigger", timeout_s=2)
            await client.send_action_goal("/nav", "nav2_msgs/NavigateToPose", {"pose": {}}, "g1")
            await client.cancel_action_goal("/nav", "g1")
            await eventually(lambda: len(bridge.requests[-1]) == 4, what="three requests")
            assert bridge.requests[-1][1:] == [
                {
                    "op": "call_service",
                    "id": "c1",
                    "service": "/reset",
                    "args": {"hard": True},
                    "type": "std_srvs/srv/Trigger",
                    "timeout": 2,
                },
                {
                    "op": "send_action_goal",
                    "id": "g1",
                    "action": "/nav",
                    "action_type": "nav2_msgs/action/NavigateToPose",
                    "args": {"pose": {}},
                    "feedback": True,
                },
                {"op": "cancel_action_goal", "id": "g1", "action": "/nav"},
            ]
            assert client.health().outstanding_calls == 2
            await bridge.send(
                publish("prompt_text", {"data": "hello"}),
                action_frame("action_feedback", "g1", {"left": 2}),
                service_response("c1", {"success": True}),
                action_frame("action_result", "g1", {}, status=5, result=True),
            )
            out = await receive_all(client, 3)
            assert out == [
                ServiceReply("c1", "/reset", True, {"success": True}),
                GoalResult("g1", "/nav", True, 5, {}),  # its pending feedback went with the result
                out[2],
            ]
            assert isinstance(out[2], Received) and out[2].msg == {"data": "hello"}
            health = client.health()
            assert (health.outstanding_calls, health.feedback_dropped, health.protocol_errors) == (0, 1, 0)
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_feedback_is_latest_wins_per_goal_and_counted() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge)
        try:
            await client.send_action_goal("/nav", "nav2_msgs/action/NavigateToPose", {}, "a")
            await client.send_action_goal("/nav", "nav2_msgs/action/NavigateToPose", {}, "b")
            await bridge.send(*(action_frame("action_feedback", "a", {"n": n}) for n in range(50)))
            await bridge.send(action_frame("action_feedback", "b", {"n": -1}))
            await eventually(lambda: client.health().feedback_dropped == 49, what="feedback read")
            assert await receive_all(client, 2) == [
                GoalFeedback("a", "/nav", {"n": 49}),
                GoalFeedback("b", "/nav", {"n": -1}),
            ]
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_failures_replies_to_unknown_ids_and_duplicate_ids() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge)
        try:
            await client.call_service("/reset", {}, 1)
            with pytest.raises(ValueError, match="already outstanding"):
                await client.call_service("/reset", {}, 1)
            with pytest.raises(ValueError):  # what the bridge would refuse is refused here
                await client.call_service("/reset", {"x": math.nan}, 2)
            with pytest.raises(ValueError):
                await client.send_action_goal("/nav", "std_msgs/msg/String", {}, 3)
            with pytest.raises(ValueError):
                await client.call_service("bad name", {}, 4)
            await bridge.send(
                service_response(99, {}),  # nobody asked
                action_frame("action_feedback", 1, {}),  # 1 is a service call, not a goal
                service_response(
                    1, "service /reset is not in the services allow-list", False, code="not_allowed"
                ),
            )
            reply = await client.receive(5)
            assert reply == ServiceReply(
                1, "/reset", False, None, "service /reset is not in the services allow-list", "not_allowed"
            )
            assert client.health().protocol_errors == 2
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_outstanding_calls_are_bounded() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, options=replace(FAST, max_outstanding_calls=2))
        try:
            await client.call_service("/reset", {}, "a")
            await client.send_action_goal("/nav", "a/B", {}, "b")
            with pytest.raises(TooManyCalls):
                await client.call_service("/reset", {}, "c")
            await bridge.send(service_response("a", {}))
            await client.receive(5)
            await client.call_service("/reset", {}, "c")
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_a_dropped_connection_fails_every_outstanding_call_and_goal() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge)
        try:
            await client.call_service("/reset", {}, "c1")
            await client.send_action_goal("/nav", "a/B", {}, "g1")
            await eventually(lambda: len(bridge.requests[-1]) == 2, what="requests")
            await bridge.connections[-1].close(1011)
            out = await receive_all(client, 2)
            assert sorted((type(d).__name__, d.id, d.ok, d.code) for d in out) == [  # type: ignore[union-attr]
                ("GoalResult", "g1", False, "disconnected"),
                ("ServiceReply", "c1", False, "disconnected"),
            ]
            assert client.health().outstanding_calls == 0
            await eventually(lambda: client.connected, what="reconnect")
            await client.cancel_action_goal("/nav", "g1")  # it already ended here: nothing is sent
            assert all(r["op"] != "cancel_action_goal" for c in bridge.requests for r in c)
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_calls_fail_loudly_when_disconnected() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge)
        await bridge.stop()
        await eventually(lambda: not client.connected, what="disconnect noticed")
        try:
            with pytest.raises(BridgeUnavailable):
                await client.call_service("/reset", {}, "c1")
            with pytest.raises(BridgeUnavailable):
                await client.send_action_goal("/nav", "a/B", {}, "g1")
            assert client.health().outstanding_calls == 0
        finally:
            await client.close()

    run(scenario())


def test_an_overdue_service_reply_and_a_goal_the_bridge_does_not_know_end_as_failures() -> None:
    async def scenario() -> None:
        bridge = await scripted()
        client = await connected_client(bridge, options=replace(FAST, reply_grace_s=0))
        try:
            await client.call_service("/reset", {}, "c1", timeout_s=0.05)
            reply = await client.receive(5)
            assert isinstance(reply, ServiceReply) and (reply.ok, reply.code) == (False, "timeout")
            await client.send_action_goal("/nav", "a/B", {}, "g1")
            await client.cancel_action_goal("/nav", "g1")
            await eventually(lambda: len(bridge.requests[-1]) == 3, what="requests")
            await bridge.send(
                json.dumps(
                    {
                        "op": "status",
                        "level": "warning",
                        "msg": "no active goal",
                        "id": "g1",
                        "code": "not_active",
                    }
                )
            )
            result = await client.receive(5)
            assert result == GoalResult("g1", "/nav", False, 0, None, "no active goal", "not_active")
            await bridge.send(service_response("c1", {}))  # too late: already failed here
            await eventually(lambda: client.health().protocol_errors == 1, what="late reply counted")
        finally:
            await client.close()
            await bridge.stop()

    run(scenario())


def test_calls_through_the_real_bridge_core_and_server() -> None:
    async def scenario() -> None:
        core, graph = make_core(BridgeParams(port=0))
        server = BridgeServer(core, "")
        await server.start()
        try:
            async with BridgeClient(f"ws://127.0.0.1:{server.port}/", FAST) as client:
                await client.wait_connected(5)
                await client.call_service("reset_pose", {}, "c1", "std_srvs/Trigger")
                await client.call_service("not_listed", {}, "c2")
                await client.send_action_goal("navigate", "nav2_msgs/NavigateToPose", {"pose": {}}, 7)
                await eventually(lambda: graph.calls and graph.goals, what="call and goal in ROS")
                graph.calls[0].done(CallOutcome(True, '{"success":true}'))
                first = await client.receive(5)
                second = await client.receive(5)
                assert {first.id: first, second.id: second} == {  # type: ignore[union-attr]
                    "c1": ServiceReply("c1", "reset_pose", True, {"success": True}),
                    "c2": ServiceReply(
                        "c2",
                        "not_listed",
                        False,
                        None,
                        "service 'not_listed' is not in the services allow-list",
                        "not_allowed",
                    ),
                }
                graph.goal().feedback('{"left":1}')
                assert await client.receive(5) == GoalFeedback(7, "navigate", {"left": 1})
                await client.cancel_action_goal("navigate", 7)
                await eventually(lambda: graph.goal().cancels == 1, what="cancel in ROS")
                graph.goal().done(CallOutcome(True, "{}", status=5))
                assert await client.receive(5) == GoalResult(7, "navigate", True, 5, {})
            await eventually(lambda: not core.sessions, what="session closed")
        finally:
            await server.stop()

    run(scenario())


def test_a_client_that_leaves_has_its_goals_cancelled_by_the_real_bridge() -> None:
    async def scenario() -> None:
        core, graph = make_core(BridgeParams(port=0))
        server = BridgeServer(core, "")
        await server.start()
        try:
            async with BridgeClient(f"ws://127.0.0.1:{server.port}/", FAST) as client:
                await client.wait_connected(5)
                await client.send_action_goal("navigate", "nav2_msgs/NavigateToPose", {}, "g")
                await eventually(lambda: graph.goals, what="goal in ROS")
            await eventually(lambda: graph.goal().cancels == 1, what="goal cancelled on disconnect")
        finally:
            await server.stop()

    run(scenario())
