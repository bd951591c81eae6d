"""Pure parts of the bridge: protocol parsing, allow-lists, auth, names, flow control, core routing."""

from __future__ import annotations

import json

import pytest
from bridge_fakes import NAMESPACE, make_core

from by_your_command.bridge.auth import InsecureBindError, check_bind, presented_token, token_matches
from by_your_command.bridge.config import BridgeParams, ConfigError, parse_allow_lists
from by_your_command.bridge.flow import SendQueue, TokenBucket
from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.protocol import (
    Advertise,
    ProtocolError,
    Publish,
    Subscribe,
    encode_request,
    parse_request,
    parse_server_frame,
)

pytestmark = pytest.mark.unit


def statuses(session: object) -> list[dict[str, object]]:
    out = []
    queue = session.queue  # type: ignore[attr-defined]
    while (text := queue.take_nowait()) is not None:
        frame = json.loads(text)
        if frame["op"] == "status":
            out.append(frame)
    return out


def test_parse_subscribe_with_rosbridge_fields() -> None:
    request = parse_request(
        '{"op":"subscribe","id":"s1","topic":"prompt_voice","type":"by_your_command_msgs/AudioDataUtterance",'
        '"throttle_rate":100,"queue_length":5}'
    )
    assert request == Subscribe("prompt_voice", "by_your_command_msgs/msg/AudioDataUtterance", 100, 5, "s1")


@pytest.mark.parametrize(
    ("frame", "fragment"),
    [
        ("{not json", "malformed JSON"),
        ("[1,2]", "JSON object"),
        ('{"topic":"x"}', "missing 'op'"),
        ('{"op":"call_service","service":"/x"}', "unsupported op"),
        ('{"op":"subscribe"}', "'topic'"),
        ('{"op":"subscribe","topic":"a//b"}', "invalid topic"),
        ('{"op":"subscribe","topic":"a","throttle_rate":-1}', "non-negative"),
        ('{"op":"subscribe","topic":"a","compression":"png"}', "compression"),
        ('{"op":"advertise","topic":"a","type":"String"}', "invalid message type"),
        ('{"op":"publish","topic":"a","msg":"hello"}', "must be a JSON object"),
    ],
)
def test_bad_requests_are_clear_errors(frame: str, fragment: str) -> None:
    with pytest.raises(ProtocolError, match=fragment):
        parse_request(frame)


def test_client_requests_round_trip_through_the_parser() -> None:
    for request in (
        Subscribe("a", "std_msgs/msg/String", 10, 2, "7"),
        Advertise("b", "std_msgs/msg/Bool"),
        Publish("b", {"data": True}),
    ):
        assert parse_request(encode_request(request)) == request


def test_allow_list_defaults_and_errors() -> None:
    allow = parse_allow_lists(
        {
            "subscribe": [
                {"topic": "cam", "type": "sensor_msgs/CompressedImage"},
                {"topic": "t", "type": "std_msgs/msg/String"},
            ]
        }
    )
    assert [(r.topic_class, r.qos) for r in allow.subscribe] == [("video", "stream"), ("text", "reliable")]
    assert allow.subscribe[0].drops_oldest and not allow.subscribe[1].drops_oldest
    for bad, fragment in [
        ({"subscribe": [{"topic": "a"}]}, "non-empty strings"),
        ({"subscribe": [{"topic": "a", "type": "x/y", "qos": "fast"}]}, "qos"),
        ({"publish": [{"topic": "a", "type": "x/y", "colour": 1}]}, "unknown keys"),
        ({"subscribers": []}, "unknown top-level"),
        ({"publish": [{"topic": "a", "type": "x/y"}, {"topic": "a", "type": "x/y"}]}, "more than once"),
    ]:
        with pytest.raises(ConfigError, match=fragment):
            parse_allow_lists(bad)


def test_bind_policy_and_token_compare() -> None:
    check_bind("127.0.0.1", "")
    check_bind("::1", "")
    check_bind("0.0.0.0", "secret")
    with pytest.raises(InsecureBindError):
        check_bind("0.0.0.0", "")
    with pytest.raises(InsecureBindError):
        check_bind("robot.local", "")
    assert presented_token("Bearer abc", "/") == "abc"
    assert presented_token(None, "/?x=1&token=q%20r") == "q r"
    assert presented_token("Basic zzz", "/") is None
    assert token_matches("", None)
    assert token_matches("abc", "abc")
    assert not token_matches("abc", "abd")
    assert not token_matches("abc", None)


def test_names_resolve_in_namespace_exactly() -> None:
    assert resolve_topic("prompt_voice", "/robot1") == "/robot1/prompt_voice"
    assert resolve_topic("/robot1/prompt_voice", "/robot1") == "/robot1/prompt_voice"
    assert resolve_topic("prompt_voice", "/") == "/prompt_voice"
    for bad in ("", "~/x", "a/", "a b", "1abc"):
        with pytest.raises(ValueError):
            resolve_topic(bad, "/ns")


def test_video_drops_oldest_and_audio_is_reported() -> None:
    queue = SendQueue(max_messages=3, max_bytes=10_000)
    for index in range(5):
        queue.put(f"v{index}", "/cam", drops_oldest=True, topic_limit=2)
    assert [queue.take_nowait(), queue.take_nowait(), queue.take_nowait()] == ["v3", "v4", None]
    assert queue.dropped == {"/cam": 3}
    for index in range(5):
        queue.put(f"a{index}", "/audio", drops_oldest=False, topic_limit=3)
    report = json.loads(queue.take_nowait() or "")
    assert report["op"] == "status" and report["code"] == "dropped" and report["counts"] == {"/audio": 2}
    assert [queue.take_nowait() for _ in range(4)] == ["a0", "a1", "a2", None]


def test_send_queue_is_bounded_in_bytes() -> None:
    queue = SendQueue(max_messages=100, max_bytes=100)
    accepted = [queue.put("x" * 40, "/audio", False, 100) for _ in range(4)]
    assert accepted == [True, True, False, False]
    assert queue.queued_bytes == 80


def test_token_bucket() -> None:
    now = [0.0]
    bucket = TokenBucket(rate=10, burst=2, clock=lambda: now[0])
    assert [bucket.allow() for _ in range(3)] == [True, True, False]
    now[0] += 0.1
    assert bucket.allow() and not bucket.allow()


def test_core_routes_exact_topics_only() -> None:
    core, graph = make_core()
    alice, bob = core.open_session("alice"), core.open_session("bob")
    core.handle_frame(alice, '{"op":"subscribe","topic":"prompt_text"}')
    core.handle_frame(bob, f'{{"op":"subscribe","topic":"{NAMESPACE}/prompt_text"}}')
    assert graph.subscribed == {"/robot1/prompt_text"}
    core.deliver("/robot1/prompt_text", '{"data":"hello"}')
    core.deliver("/other/prompt_text", '{"data":"not for you"}')  # same last segment, other robot
    alice_frame = json.loads(alice.queue.take_nowait() or "")
    bob_frame = json.loads(bob.queue.take_nowait() or "")
    assert alice_frame == {"op": "publish", "topic": "prompt_text", "msg": {"data": "hello"}}
    assert bob_frame["topic"] == "/robot1/prompt_text"
    assert alice.queue.take_nowait() is None and bob.queue.take_nowait() is None
    core.close_session(alice)
    assert graph.subscribed == {"/robot1/prompt_text"}
    core.handle_frame(bob, '{"op":"unsubscribe","topic":"prompt_text"}')
    assert graph.subscribed == set()


def test_core_refusals_are_status_errors() -> None:
    core, graph = make_core(BridgeParams(port=0, max_message_bytes=200))
    session = core.open_session("peer")
    frames = [
        "{oops",
        '{"op":"subscribe","topic":"secret_topic"}',
        '{"op":"subscribe","topic":"/prompt_text"}',  # outside our namespace
        '{"op":"subscribe","topic":"prompt_text","type":"std_msgs/Bool"}',
        '{"op":"publish","topic":"prompt_text","msg":{"data":"x"}}',  # subscribe-only
        '{"op":"advertise","topic":"response_text","type":"std_msgs/Int32"}',
        '{"op":"publish","id":"p9","topic":"response_text","msg":{"data":5}}',
        '{"op":"publish","topic":"response_text","msg":{"data":"' + "x" * 300 + '"}}',
        '{"op":"unsubscribe","topic":"prompt_text"}',
    ]
    for frame in frames:
        core.handle_frame(session, frame)
    codes = [(s["level"], s["code"]) for s in statuses(session)]
    assert codes == [
        ("error", "bad_request"),
        ("error", "not_allowed"),
        ("error", "not_allowed"),
        ("error", "wrong_type"),
        ("error", "not_allowed"),
        ("error", "wrong_type"),
        ("error", "bad_message"),
        ("error", "too_large"),
        ("warning", "not_subscribed"),
    ]
    assert session.rejected == len(frames)
    assert graph.published == []
    core.handle_frame(session, '{"op":"publish","topic":"response_text","msg":{"data":"ok"}}')
    assert graph.published == [("/robot1/response_text", {"data": "ok"})]


def test_core_rate_limit() -> None:
    core, graph = make_core(BridgeParams(port=0, rate_limit_per_s=1.0, rate_burst=3))
    session = core.open_session("flood")
    for _ in range(5):
        core.handle_frame(session, '{"op":"publish","topic":"response_text","msg":{"data":"x"}}')
    assert len(graph.published) == 3
    assert [s["code"] for s in statuses(session)] == ["rate_limited", "rate_limited"]


def test_core_throttle_and_state_replay() -> None:
    now = [0.0]
    core, _ = make_core()
    core._clock = lambda: now[0]
    session = core.open_session("p")
    core.deliver("/robot1/voice_activity", '{"data":true}')  # before anyone subscribed
    core.handle_frame(session, '{"op":"subscribe","topic":"voice_activity"}')
    assert json.loads(session.queue.take_nowait() or "")["msg"] == {"data": True}
    core.handle_frame(session, '{"op":"subscribe","topic":"prompt_text","throttle_rate":100}')
    for step in range(10):
        now[0] = step * 0.03
        core.deliver("/robot1/prompt_text", f'{{"data":"{step}"}}')
    received = []
    while (text := session.queue.take_nowait()) is not None:
        received.append(json.loads(text)["msg"]["data"])
    assert received == ["0", "4", "8"]


def test_client_side_frame_parser() -> None:
    frame = parse_server_frame(
        '{"op":"status","level":"warning","msg":"m","code":"dropped","counts":{"/a":2}}'
    )
    assert frame.counts == {"/a": 2}  # type: ignore[union-attr]
    with pytest.raises(ProtocolError):
        parse_server_frame('{"op":"weird"}')
