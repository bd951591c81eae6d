"""Shared helpers for bridge tests: a fake RosGraph and a server running on loopback."""

from __future__ import annotations

import asyncio
import base64
import os
import socket
import struct
import threading
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field, replace
from typing import Any

from by_your_command.bridge.calls import ActionRule, CallOutcome, ServiceRule
from by_your_command.bridge.config import AllowLists, BridgeParams, TopicRule, parse_allow_lists
from by_your_command.bridge.core import BridgeCore, PublishError
from by_your_command.bridge.server import BridgeServer

ALLOW = parse_allow_lists(
    {
        "subscribe": [
            {"topic": "prompt_voice", "type": "by_your_command_msgs/msg/AudioDataUtterance"},
            {"topic": "prompt_text", "type": "std_msgs/msg/String"},
            {"topic": "voice_activity", "type": "std_msgs/msg/Bool"},
            {"topic": "camera_forwarded", "type": "sensor_msgs/msg/CompressedImage"},
        ],
        "publish": [
            {"topic": "response_text", "type": "std_msgs/msg/String"},
            {"topic": "response_cmd", "type": "std_msgs/msg/String", "class": "command"},
        ],
        "services": [
            {"name": "reset_pose", "type": "std_srvs/srv/Trigger", "timeout_s": 5},
            {"name": "/global/set_flag", "type": "std_srvs/SetBool"},
        ],
        "actions": [
            {"name": "navigate", "type": "nav2_msgs/action/NavigateToPose", "timeout_s": 3},
        ],
    }
)
NAMESPACE = "/robot1"


@dataclass
class FakeCall:
    """A service call the core made; the test answers it with `done`."""

    rule: ServiceRule
    full_name: str
    request: Any
    timeout_s: float
    done: Callable[[CallOutcome], None]


@dataclass
class FakeGoal:
    """A goal the core sent; the test drives `feedback` and `done`."""

    rule: ActionRule
    full_name: str
    goal: Any
    token: int
    feedback: Callable[[str], None]
    done: Callable[[CallOutcome], None]
    cancels: int = 0


@dataclass
class ConvertedCall:
    type_name: str
    part: str
    args: dict[str, Any]
    thread: int = field(default_factory=threading.get_ident)


class FakeGraph:
    """Records what the core asks of ROS; rejects a non-string `data` like the real converter.

    `hold(text)` makes the conversion of a message whose `data` is `text` block (on its worker
    thread) until `release(text)`: tests can prove what happens while a conversion is running.
    Services and actions are scripted by the test: calls and goals are recorded and answered by
    calling their `done`/`feedback`; a call's args with key "bad" fail conversion (bad_args).
    """

    def __init__(self) -> None:
        self.subscribed: set[str] = set()
        self.advertised: set[str] = set()
        self.published: list[tuple[str, dict[str, Any]]] = []
        self.converting: set[str] = set()  # held conversions that have started
        self._holds: dict[str, threading.Event] = {}
        self.converted_calls: list[ConvertedCall] = []
        self.calls: list[FakeCall] = []
        self.goals: dict[int, FakeGoal] = {}  # by token
        self.fail_next: Exception | None = None  # raised by the next call_service/send_goal

    def hold(self, data: str) -> None:
        self._holds[data] = threading.Event()

    def release(self, data: str) -> None:
        self._holds[data].set()

    def subscribe(self, rule: TopicRule, full_topic: str) -> None:
        self.subscribed.add(full_topic)

    def unsubscribe(self, full_topic: str) -> None:
        self.subscribed.discard(full_topic)

    def advertise(self, rule: TopicRule, full_topic: str) -> None:
        self.advertised.add(full_topic)

    def convert(self, rule: TopicRule, msg: dict[str, Any]) -> Any:
        if set(msg) - {"data"}:
            raise PublishError(f"unknown field(s) {sorted(set(msg) - {'data'})}")
        data = msg.get("data", "")
        if not isinstance(data, str):
            raise PublishError("data: expected a string")
        hold = self._holds.get(data)
        if hold is not None:
            self.converting.add(data)
            if not hold.wait(10):
                raise RuntimeError(f"test never released the conversion of {data[:20]!r}")
        return msg

    def publish(self, rule: TopicRule, full_topic: str, message: Any) -> None:
        self.published.append((full_topic, message))

    def convert_call(self, type_name: str, part: str, args: dict[str, Any]) -> Any:
        if "bad" in args:
            raise PublishError("bad: no such field")
        self.converted_calls.append(ConvertedCall(type_name, part, args))
        return {"converted": args}

    def _maybe_fail(self) -> None:
        error, self.fail_next = self.fail_next, None
        if error is not None:
            raise error

    def call_service(
        self,
        rule: ServiceRule,
        full_name: str,
        request: Any,
        timeout_s: float,
        done: Callable[[CallOutcome], None],
    ) -> None:
        self._maybe_fail()
        self.calls.append(FakeCall(rule, full_name, request, timeout_s, done))

    def send_goal(
        self,
        rule: ActionRule,
        full_name: str,
        goal: Any,
        token: int,
        feedback: Callable[[str], None],
        done: Callable[[CallOutcome], None],
    ) -> None:
        self._maybe_fail()
        self.goals[token] = FakeGoal(rule, full_name, goal, token, feedback, done)

    def cancel_goal(self, token: int) -> None:
        self.goals[token].cancels += 1

    def goal(self, index: int = -1) -> FakeGoal:
        return list(self.goals.values())[index]


def make_core(params: BridgeParams | None = None, allow: AllowLists = ALLOW) -> tuple[BridgeCore, FakeGraph]:
    graph = FakeGraph()
    return BridgeCore(params or BridgeParams(port=0), allow, graph, NAMESPACE), graph


@asynccontextmanager
async def running_bridge(token: str = "", **overrides: Any) -> AsyncIterator[tuple[BridgeServer, FakeGraph]]:
    params = replace(BridgeParams(port=0), **overrides)
    core, graph = make_core(params)
    server = BridgeServer(core, token)
    await server.start()
    try:
        yield server, graph
    finally:
        await server.stop()


async def eventually(condition: Any, timeout: float = 5.0, what: str = "") -> Any:
    """Async twin of byc_testing.wait_for: poll without blocking the loop, never a fixed sleep."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        value = condition()
        if value:
            return value
        if loop.time() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what or condition}")
        await asyncio.sleep(0.005)


def raw_websocket(port: int) -> socket.socket:
    """A WebSocket client on a bare socket, past the handshake: it sends what a test prebuilt
    (allocating nothing, so the bridge's memory can be traced alone) and reads nothing."""
    sock = socket.create_connection(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
    )
    response = b""
    while b"\r\n\r\n" not in response:
        response += sock.recv(1)  # byte by byte: nothing after the response is consumed
    assert response.startswith(b"HTTP/1.1 101 "), response
    return sock


def masked_text_frame(text: str) -> bytes:
    """One client text frame (all-zero mask: the payload goes as is)."""
    payload = text.encode()
    if len(payload) < 126:
        header = bytes([0x81, 0x80 | len(payload)])
    elif len(payload) < 65_536:
        header = bytes([0x81, 0x80 | 126]) + struct.pack(">H", len(payload))
    else:
        header = bytes([0x81, 0x80 | 127]) + struct.pack(">Q", len(payload))
    return header + bytes(4) + payload
