"""Hostile frames over a real WebSocket to the real ros_ai_bridge node (real converter, real DDS).

Each hostile frame is followed by a sentinel request whose refusal carries a known id: every frame
is answered before the sentinel's reply (0 hangs: each wait has a generous bound), a frame the
parser refuses gets exactly one `bad_request`/`too_large` status, no reply is an internal error,
and a connection is only ever closed with a policy code (1007/1008/1009, never 1011 or an abrupt
drop). Afterwards a well-behaved client subscribes and publishes through the same bridge.
"""

from __future__ import annotations

import contextlib
import json
import re
import subprocess
import threading
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from byc_testing import INSTALL_LIB, running_process, wait_for
from call_frames import call_frames
from fuzzing import TALLY, fuzz_settings, hostile_frames
from hypothesis import given
from rclpy.node import Node
from ros_messages import ALLOW, publish_frames
from std_msgs.msg import String
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from by_your_command.bridge.protocol import CallService, ProtocolError, SendActionGoal, parse_request
from by_your_command.nodes import _qos

pytestmark = [pytest.mark.ros, pytest.mark.timeout(1800)]

MAX_MESSAGE_BYTES = 65_536  # small, so oversize frames are cheap to make
POLICY_CLOSES = {1007, 1008, 1009}  # invalid data, policy violation, too big
REPLY_BOUND_S = 30.0  # the bound on any answer: generous for a loaded 2-core machine
SUBSCRIBABLE = [rule.topic for rule in ALLOW.subscribe] + ["no_such_topic"]
PUBLISHABLE = [rule.topic for rule in ALLOW.publish] + ["prompt_voice"]
# Calls and goals: to names that are not allow-listed (refused) and to tools' ones if any; a real
# call may be answered later (after the sentinel), which every exchange tolerates.
CALLS = call_frames(["no_such_service", "/no/such/service"], ["no_such_action", "navigate_to_pose"])
FRAMES = hostile_frames(SUBSCRIBABLE, PUBLISHABLE) | publish_frames() | CALLS
REPLY_OPS = {"status", "publish", "service_response", "action_feedback", "action_result"}


class Output:
    """The node's output lines, collected on a thread."""

    def __init__(self, process: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        threading.Thread(target=self._pump, args=(process,), daemon=True).start()

    def _pump(self, process: subprocess.Popen[str]) -> None:
        assert process.stdout is not None
        for line in process.stdout:
            self.lines.append(line.rstrip("\n"))

    def find(self, pattern: str) -> re.Match[str] | None:
        return next((m for line in list(self.lines) if (m := re.search(pattern, line))), None)


@dataclass
class Bridge:
    namespace: str
    port: int
    process: subprocess.Popen[str]
    output: Output
    connection: ClientConnection | None = None
    closes: list[int] = field(default_factory=list)
    sentinels: int = 0
    connections: contextlib.ExitStack = field(default_factory=contextlib.ExitStack)

    def connect(self) -> ClientConnection:
        if self.connection is None:
            self.connection = self.connections.enter_context(
                connect(f"ws://127.0.0.1:{self.port}/", max_size=None, open_timeout=REPLY_BOUND_S)
            )
        return self.connection

    def closed(self, error: ConnectionClosed) -> int:
        code = error.rcvd.code if error.rcvd is not None else 1006
        self.closes.append(code)
        self.connection = None
        return code


@pytest.fixture(scope="module")
def bridge() -> Iterator[Bridge]:
    namespace = f"/fuzz_{uuid.uuid4().hex[:10]}"
    args = [
        str(INSTALL_LIB / "ros_ai_bridge"),
        "--ros-args",
        "-r",
        f"__ns:={namespace}",
        "-p",
        "port:=0",
        "-p",
        f"max_message_bytes:={MAX_MESSAGE_BYTES}",
        "-p",
        "inline_convert_bytes:=2048",  # larger publishes take the worker-thread path
        "-p",
        "rate_limit_per_s:=100000.0",
        "-p",
        "rate_burst:=100000",
    ]
    with running_process(args) as process:
        output = Output(process)
        match = wait_for(
            lambda: output.find(r"listening on 127\.0\.0\.1:(\d+)") or process.poll() is not None,
            timeout=60,
            what="bridge startup",
        )
        assert isinstance(match, re.Match), "\n".join(output.lines)
        bridge = Bridge(namespace, int(match.group(1)), process, output)
        with bridge.connections:
            yield bridge


def expected_refusal(frame: str | bytes) -> str | None:
    """The code a frame must be refused with, when the pure parser already refuses it."""
    size = len(frame if isinstance(frame, bytes) else frame.encode("utf-8", "surrogatepass"))
    if size > MAX_MESSAGE_BYTES:
        return "too_large"
    try:
        parse_request(frame)
    except ProtocolError:
        return "bad_request"
    return None


def exchange(bridge: Bridge, frame: str | bytes | list[str]) -> list[dict[str, Any]] | int:
    """Send `frame` then a sentinel; the replies before the sentinel's, or the close code."""
    bridge.sentinels += 1
    sentinel = f"sentinel-{bridge.sentinels}"
    try:
        connection = bridge.connect()
        connection.send(frame)
        connection.send(json.dumps({"op": "unsubscribe", "topic": "never_subscribed", "id": sentinel}))
        replies = []
        while True:
            reply = json.loads(connection.recv(timeout=REPLY_BOUND_S))  # TimeoutError here = a hang
            if reply.get("id") == sentinel:
                assert reply["code"] == "not_subscribed", reply
                return replies
            replies.append(reply)
    except ConnectionClosed as error:
        return bridge.closed(error)


def check_answer(frame: str | bytes, answer: list[dict[str, Any]] | int) -> None:
    if isinstance(answer, int):
        assert answer in POLICY_CLOSES, f"closed with {answer} after {str(frame)[:200]!r}"
        return
    statuses = [reply for reply in answer if reply["op"] == "status"]
    assert all(reply["op"] in REPLY_OPS for reply in answer), answer
    assert not any(status.get("code") == "internal_error" for status in statuses), statuses
    assert len([s for s in statuses if s["level"] == "error"]) <= 1, statuses
    expected = expected_refusal(frame)
    if expected is not None:
        assert [s["code"] for s in statuses] == [expected], (str(frame)[:200], statuses)
    request = _parsed(frame)
    if expected is None and isinstance(request, (CallService, SendActionGoal)) and statuses:
        # A refused call is also answered as failed, with its id (what roslibpy's errback needs).
        op = "service_response" if isinstance(request, CallService) else "action_result"
        failed = [r for r in answer if r["op"] == op and r["id"] == request.id and r["result"] is False]
        assert failed, (str(frame)[:200], answer)  # more only if an earlier call's late reply shares the id


def _parsed(frame: str | bytes) -> object:
    try:
        return parse_request(frame)
    except ProtocolError:
        return None


def sendable(frame: str | bytes) -> str | bytes:
    """A text frame must be UTF-8: text with lone surrogates goes as the same bytes, in a binary frame."""
    if isinstance(frame, str):
        try:
            frame.encode("utf-8")
        except UnicodeEncodeError:
            return frame.encode("utf-8", "surrogatepass")
    return frame


@fuzz_settings(short=60, long=2_000)
@given(FRAMES.map(sendable))
def test_hostile_frames_over_a_real_websocket_are_answered_never_crash(
    bridge: Bridge, frame: str | bytes
) -> None:
    with TALLY.input("ros_ai_bridge node (WebSocket)"):
        check_answer(frame, exchange(bridge, frame))
        assert bridge.process.poll() is None, "\n".join(bridge.output.lines[-30:])


WIRE_ODDITIES: list[tuple[str, Any]] = [
    ("4x oversize text", "x" * (4 * MAX_MESSAGE_BYTES + 1)),
    ("4x oversize binary", b"\x00" * (4 * MAX_MESSAGE_BYTES + 1)),
    ("just oversize", '{"op":"publish","topic":"response_text","msg":{"data":"' + "€" * 30_000 + '"}}'),
    ("fragmented", ['{"op":"subscribe",', '"topic":"prompt_text"}']),
    ("empty text", ""),
    ("empty binary", b""),
    ("invalid UTF-8 in a text frame", b"\xff\xfe{}"),
    (
        "huge array publish",
        '{"op":"publish","topic":"response_voice","msg":{"data":[' + "1," * 30_000 + "1]}}",
    ),
    ("deep publish", '{"op":"publish","topic":"response_text","msg":' + "[" * 40 + "]" * 40 + "}"),
]


@pytest.mark.parametrize(("name", "frame"), WIRE_ODDITIES, ids=[case[0] for case in WIRE_ODDITIES])
def test_wire_level_oddities_get_a_status_or_a_policy_close(bridge: Bridge, name: str, frame: Any) -> None:
    if name == "invalid UTF-8 in a text frame":
        connection = bridge.connect()
        connection.send(frame, text=True)  # websockets lets a client send bytes as a text frame
        with pytest.raises(ConnectionClosed) as closed:
            connection.recv(timeout=REPLY_BOUND_S)
        assert bridge.closed(closed.value) == 1007
        return
    answer = exchange(bridge, frame)
    if isinstance(answer, int) or name.startswith("4x"):
        assert answer == 1009, (name, answer)
    else:
        check_answer(frame if isinstance(frame, (str, bytes)) else "".join(frame), answer)


def test_the_bridge_still_serves_a_well_behaved_client_afterwards(bridge: Bridge, graph_node: Node) -> None:
    """Runs after the fuzzing above (same module, same bridge process)."""
    assert bridge.process.poll() is None
    assert not bridge.output.find(r"internal error|Traceback|connection handler failed|send loop failed"), (
        "\n".join(bridge.output.lines[-40:])
    )
    assert not set(bridge.closes) - POLICY_CLOSES, bridge.closes
    heard: list[str] = []
    graph_node.create_subscription(
        String, f"{bridge.namespace}/response_text", lambda m: heard.append(m.data), _qos.RELIABLE
    )
    publisher = graph_node.create_publisher(String, f"{bridge.namespace}/prompt_text", _qos.RELIABLE)
    with connect(f"ws://127.0.0.1:{bridge.port}/", open_timeout=REPLY_BOUND_S) as polite:
        polite.send('{"op":"subscribe","topic":"prompt_text"}')
        polite.send('{"op":"advertise","topic":"response_text","type":"std_msgs/String"}')
        polite.send('{"op":"unsubscribe","topic":"never_subscribed","id":"done"}')
        assert json.loads(polite.recv(timeout=REPLY_BOUND_S))["id"] == "done"  # both requests applied
        wait_for(lambda: publisher.get_subscription_count() > 0, timeout=60, what="bridge subscribed")
        publisher.publish(String(data="still here"))
        reply = json.loads(polite.recv(timeout=REPLY_BOUND_S))
        assert (reply["op"], reply["msg"]) == ("publish", {"data": "still here"})
        wait_for(lambda: graph_node.count_publishers(f"{bridge.namespace}/response_text") > 0, timeout=60)
        polite.send('{"op":"publish","topic":"response_text","msg":{"data":"and me"}}')
        wait_for(lambda: heard == ["and me"], timeout=60, what="the publish reaching ROS")
