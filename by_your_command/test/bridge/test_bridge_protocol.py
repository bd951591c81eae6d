"""Pure parts of the bridge: protocol parsing, allow-lists, auth, names, flow control, core routing."""

from __future__ import annotations

import json

import pytest
from bridge_fakes import NAMESPACE, make_core

from by_your_command.bridge.auth import InsecureBindError, check_bind, presented_token, token_matches
from by_your_command.bridge.config import BridgeParams, ConfigError, parse_allow_lists
from by_your_command.bridge.flow import LogLimiter, SendQueue, TokenBucket
from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.protocol import (
    Advertise,
    CallService,
    CancelActionGoal,
    GoalFeedback,
    GoalResult,
    ProtocolError,
    Publish,
    SendActionGoal,
    ServiceReply,
    Subscribe,
    encode_action_failure,
    encode_action_feedback,
    encode_action_result,
    encode_request,
    encode_service_failure,
    encode_service_response,
    normalize_interface,
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
        ('{"op":"call_service","service":"/x"}', "needs an 'id'"),
        ('{"op":"advertise_service","service":"/x","type":"a/B"}', "unsupported op"),
        ('{"op":"call_service","id":1,"service":"a//b"}', "invalid service name"),
        ('{"op":"call_service","id":1,"service":"/x","args":[1]}', "'args' must be a JSON object"),
        ('{"op":"call_service","id":1,"service":"/x","type":"a/msg/B"}', "invalid srv type"),
        ('{"op":"call_service","id":1,"service":"/x","timeout":0}', "'timeout'"),
        ('{"op":"call_service","id":1,"service":"/x","timeout":3601}', "'timeout'"),
        ('{"op":"call_service","id":1,"service":"/x","timeout":true}', "'timeout'"),
        ('{"op":"call_service","id":1,"service":"/x","compression":"cbor"}', "compression"),
        ('{"op":"send_action_goal","id":1,"action":"/a","args":{}}', "'action_type'"),
        ('{"op":"send_action_goal","id":1,"action":"/a","action_type":"p/srv/T"}', "invalid action type"),
        ('{"op":"send_action_goal","id":1,"action":"/a","action_type":"p/T","feedback":1}', "'feedback'"),
        ('{"op":"send_action_goal","action":"/a","action_type":"p/T"}', "needs an 'id'"),
        ('{"op":"cancel_action_goal","id":"g"}', "'action'"),
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


def test_send_queue_counts_bytes_of_utf8_not_characters() -> None:
    queue = SendQueue(max_messages=100, max_bytes=100)
    assert not queue.put("€" * 40, "/text", False, 100)  # 40 characters, 120 bytes
    assert queue.put("é" * 40, "/text", False, 100) and queue.queued_bytes == 80
    assert queue.dropped == {"/text": 1}


def test_status_replies_count_towards_the_queue_byte_bound() -> None:
    queue = SendQueue(max_messages=100, max_bytes=1000, max_control_bytes=600)
    assert queue.put("x" * 900, "/audio", False, 100)
    assert not queue.put_control("s" * 200, "bad_request")  # within its own bound, not the queue's
    assert queue.queued_bytes == 900
    assert queue.take_nowait() is not None and queue.take_nowait() == "x" * 900  # summary, then data
    assert queue.put_control("s" * 200, "bad_request") and queue.queued_bytes == 200
    assert not queue.put("y" * 900, "/audio", False, 100)  # the queued reply takes its share


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


# --- hostile input: numbers, nesting, sizes, ids ---------------------------------------------------


@pytest.mark.parametrize(
    ("frame", "fragment"),
    [
        ('{"op":"subscribe","topic":"a","throttle_rate":NaN}', "NaN is not a JSON number"),
        ('{"op":"subscribe","topic":"a","queue_length":1e400}', "out of range"),
        ('{"op":"subscribe","topic":"a","queue_length":-Infinity}', "-Infinity is not a JSON number"),
        ('{"op":"subscribe","topic":"a","queue_length":' + "9" * 5000 + "}", "number is too large"),
        ('{"op":"subscribe","topic":"a","queue_length":' + "9" * 30 + "}", "up to 2147483647"),
        ('{"op":"publish","topic":"a","msg":{"data":' + "[" * 100 + "]" * 100 + "}}", "deeper than 32"),
        ('{"op":"publish","topic":"a","msg":' + "[" * 100_000 + "]" * 100_000 + "}", "deeper than 32"),
        ('{"op":"publish","topic":"a","msg":{"x":0.' + "1" * 100 + "}}", "too long"),
    ],
)
def test_hostile_numbers_and_nesting_are_protocol_errors(frame: str, fragment: str) -> None:
    with pytest.raises(ProtocolError, match=fragment):
        parse_request(frame)


def test_hostile_frames_become_status_errors_and_the_session_goes_on() -> None:
    core, graph = make_core(BridgeParams(port=0, inline_convert_bytes=1_000_000))  # all on this thread
    session = core.open_session("hostile")
    for frame in (
        '{"op":"subscribe","topic":"prompt_text","throttle_rate":NaN}',
        '{"op":"subscribe","topic":"prompt_text","queue_length":1e400}',
        '{"op":"publish","topic":"response_text","msg":{"data":' + "7" * 5000 + "}}",
        "[" * 50_000 + "]" * 50_000,
    ):
        core.handle_frame(session, frame)
    assert [s["code"] for s in statuses(session)] == ["bad_request"] * 4
    core.handle_frame(session, '{"op":"publish","topic":"response_text","msg":{"data":"ok"}}')
    assert graph.published == [("/robot1/response_text", {"data": "ok"})]


def test_size_limit_counts_bytes_not_characters() -> None:
    core, graph = make_core(BridgeParams(port=0, max_message_bytes=1_000_000))
    session = core.open_session("euro")
    euros = "€" * 600_000  # 1.8 MB of UTF-8 in 600,000 characters
    core.handle_frame(session, '{"op":"publish","topic":"response_text","msg":{"data":"' + euros + '"}}')
    [status] = statuses(session)
    assert status["code"] == "too_large" and "1800" in str(status["msg"])
    assert graph.published == []


def test_request_ids_come_back_as_the_same_json_value() -> None:
    core, _ = make_core()
    session = core.open_session("ids")
    for request_id in (7, "s7", -3, 0):
        core.handle_frame(session, json.dumps({"op": "subscribe", "id": request_id, "topic": "secret"}))
    assert [s["id"] for s in statuses(session)] == [7, "s7", -3, 0]
    for bad_id in (True, 1.5, [1], {"a": 1}, "x" * 1000, 2**70):
        core.handle_frame(session, json.dumps({"op": "subscribe", "id": bad_id, "topic": "prompt_text"}))
    refused = statuses(session)
    assert [s["code"] for s in refused] == ["bad_request"] * 6
    assert all("id" not in s and "'id' must be" in str(s["msg"]) for s in refused)
    assert core.subscribed_topics() == []


def test_refusals_never_echo_huge_client_strings() -> None:
    core, _ = make_core(BridgeParams(port=0, inline_convert_bytes=1_000_000))  # all on this thread
    session = core.open_session("echo")
    huge = "t" * 200_000
    core.handle_frame(session, json.dumps({"op": "subscribe", "topic": huge}))
    core.handle_frame(session, json.dumps({"op": "fly" + huge}))
    core.handle_frame(session, json.dumps({"op": "publish", "topic": "response_text", "msg": {huge: 1}}))
    core.handle_frame(
        session, json.dumps({"op": "publish", "topic": "response_text", "msg": {"data": [huge]}})
    )
    replies = [json.dumps(s) for s in statuses(session)]
    assert len(replies) == 4 and all(len(reply) < 600 for reply in replies), replies


def test_status_replies_are_bounded_in_bytes_and_coalesced() -> None:
    params = BridgeParams(port=0, status_queue_bytes=4096, rate_burst=100_000)
    core, _ = make_core(params)
    session = core.open_session("never reads")
    for index in range(2000):
        core.handle_frame(
            session, json.dumps({"op": "subscribe", "id": "r" * 100, "topic": f"no_such_{index}"})
        )
    assert session.queue.queued_control_bytes <= 4096
    replies = statuses(session)
    summary = replies[0]
    assert summary["code"] == "suppressed"
    individual = [r for r in replies if r["code"] == "not_allowed"]
    assert summary["counts"] == {"not_allowed": 2000 - len(individual)}
    assert core.totals().status_suppressed == 2000 - len(individual) and core.totals().rejected == 2000


def test_refusal_log_lines_are_rate_limited_across_clients(caplog: pytest.LogCaptureFixture) -> None:
    now = [0.0]
    core, _ = make_core(BridgeParams(port=0, refusal_logs_per_s=2.0))
    core._log_limiter = LogLimiter(2.0, clock=lambda: now[0])  # a frozen clock: no refill during the flood
    with caplog.at_level("WARNING", logger="by_your_command.bridge.core"):
        for client in range(100):  # reconnecting does not reset the budget
            session = core.open_session(f"flood{client}")
            for _ in range(5):
                core.handle_frame(session, "{oops")
            core.close_session(session)
        assert len(caplog.records) == 20
        now[0] += 1.0
        core.handle_frame(core.open_session("later"), "{oops")
    assert "480 refusal log line(s) suppressed" in caplog.records[-1].getMessage()


def test_totals_keep_counting_after_clients_leave() -> None:
    core, _ = make_core(BridgeParams(port=0, send_queue_messages=2))
    session = core.open_session("slow")
    core.handle_frame(session, '{"op":"subscribe","topic":"prompt_text"}')
    core.handle_frame(session, "{oops")
    for index in range(5):
        core.deliver("/robot1/prompt_text", f'{{"data":"{index}"}}')
    core.report_lost("/robot1/prompt_text", 4)
    session.sent_messages, session.sent_bytes = 2, 40
    core.close_session(session)
    totals = core.totals()
    assert (totals.dropped, totals.rejected, totals.received, totals.lost_upstream) == (3, 1, 2, 4)
    assert (totals.sent_messages, totals.sent_bytes, totals.connections) == (2, 40, 1)
    assert core.stats() == []


def test_upstream_losses_are_reported_to_subscribers() -> None:
    core, _ = make_core()
    session = core.open_session("listener")
    core.handle_frame(session, '{"op":"subscribe","topic":"prompt_voice"}')
    core.deliver("/robot1/prompt_voice", '{"chunk_sequence":0}')
    core.report_lost("/robot1/prompt_voice", 3)
    core.deliver("/robot1/prompt_voice", '{"chunk_sequence":4}')
    frames = []
    while (text := session.queue.take_nowait()) is not None:
        frames.append(json.loads(text))
    assert frames[0]["op"] == "status" and frames[0]["code"] == "lost"
    assert frames[0]["counts"] == {"/robot1/prompt_voice": 3}
    assert [f["msg"]["chunk_sequence"] for f in frames[1:]] == [0, 4]


def test_state_of_a_topic_without_publisher_is_forgotten() -> None:
    core, _ = make_core()
    early = core.open_session("early")
    core.handle_frame(early, '{"op":"subscribe","topic":"voice_activity"}')
    core.deliver("/robot1/voice_activity", '{"data":true}')
    assert json.loads(early.queue.take_nowait() or "")["msg"] == {"data": True}
    core.forget_state("/robot1/voice_activity")
    told = json.loads(early.queue.take_nowait() or "")
    assert (told["code"], told["topic"]) == ("publisher_gone", "voice_activity")
    late = core.open_session("late")
    core.handle_frame(late, '{"op":"subscribe","topic":"voice_activity"}')
    assert late.queue.take_nowait() is None  # no stale "the user is speaking"
    core.deliver("/robot1/voice_activity", '{"data":false}')  # a new publisher: remembered again
    core.handle_frame(core.open_session("later"), '{"op":"subscribe","topic":"voice_activity"}')
    assert json.loads(core.sessions[-1].queue.take_nowait() or "")["msg"] == {"data": False}


def test_a_message_taken_after_its_publisher_left_is_passed_on_but_not_remembered() -> None:
    core, _ = make_core()
    early = core.open_session("early")
    core.handle_frame(early, '{"op":"subscribe","topic":"voice_activity"}')
    core.deliver("/robot1/voice_activity", '{"data":true}')
    core.forget_state("/robot1/voice_activity")
    core.deliver("/robot1/voice_activity", '{"data":true}', current=False)  # was in the reader queue
    frames = [json.loads(text) for text in iter(early.queue.take_nowait, None)]
    assert [f["code"] for f in frames if f["op"] == "status"] == ["publisher_gone"]
    assert [f["msg"] for f in frames if f["op"] == "publish"] == [{"data": True}, {"data": True}]
    late = core.open_session("late")
    core.handle_frame(late, '{"op":"subscribe","topic":"voice_activity"}')
    assert late.queue.take_nowait() is None


# --- services and actions (issue 35) ------------------------------------------------------------


def test_parse_call_ops_as_roslibpy_sends_them() -> None:
    call = parse_request(
        '{"op":"call_service","id":"call_service:/x:1","service":"/x","args":{"a":1},'
        '"type":"std_srvs/Trigger","timeout":2.5,"fragment_size":1000}'
    )
    assert call == CallService("/x", {"a": 1}, "call_service:/x:1", "std_srvs/srv/Trigger", 2.5)
    assert parse_request('{"op":"call_service","id":3,"service":"x"}') == CallService("x", {}, 3)
    goal = parse_request(
        '{"op":"send_action_goal","id":7,"action":"nav","action_type":"nav2_msgs/action/NavigateToPose",'
        '"args":{"pose":{}},"feedback":true}'
    )
    assert goal == SendActionGoal("nav", "nav2_msgs/action/NavigateToPose", {"pose": {}}, 7, True)
    assert (
        parse_request('{"op":"send_action_goal","id":7,"action":"a","action_type":"p/T"}').feedback is False
    )
    assert parse_request('{"op":"cancel_action_goal","id":7,"action":"nav"}') == CancelActionGoal("nav", 7)
    for request in (call, goal, CancelActionGoal("nav", "g1"), CallService("/x", {}, 1)):
        assert parse_request(encode_request(request)) == request


def test_a_refused_call_names_its_target_only_when_the_name_was_valid() -> None:
    with pytest.raises(ProtocolError) as refused:
        parse_request('{"op":"call_service","id":1,"service":"/x","args":"no"}')
    assert (refused.value.request_id, refused.value.op, refused.value.target) == (1, "call_service", "/x")
    with pytest.raises(ProtocolError) as refused:
        parse_request('{"op":"call_service","id":1,"service":"x y"}')
    assert refused.value.target == ""


def test_interface_types_are_normalised_per_kind() -> None:
    assert normalize_interface("std_srvs/Trigger", "srv") == "std_srvs/srv/Trigger"
    assert normalize_interface("std_srvs/srv/Trigger", "srv") == "std_srvs/srv/Trigger"
    assert normalize_interface("nav2_msgs/NavigateToPose", "action") == "nav2_msgs/action/NavigateToPose"
    for bad, kind in [("std_msgs/msg/String", "srv"), ("a/srv/B", "action"), ("B", "srv"), ("a/B\n", "srv")]:
        with pytest.raises(ValueError):
            normalize_interface(bad, kind)  # type: ignore[arg-type]


def test_call_frames_encode_once_and_parse_back_on_the_client_side() -> None:
    frames = [
        encode_service_response("/x", "c1", '{"success":true}'),
        encode_service_failure("/x", 5, "no server", "no_server"),
        encode_action_feedback("nav", "g", '{"left":2.5}'),
        encode_action_result("nav", "g", 4, '{"done":1}'),
        encode_action_failure("nav", "g", 0, "goal rejected", "rejected"),
    ]
    for frame in frames:
        json.loads(frame)  # valid JSON, whatever was spliced in
    assert [parse_server_frame(frame) for frame in frames] == [
        ServiceReply("c1", "/x", True, {"success": True}),
        ServiceReply(5, "/x", False, None, "no server", "no_server"),
        GoalFeedback("g", "nav", {"left": 2.5}),
        GoalResult("g", "nav", True, 4, {"done": 1}),
        GoalResult("g", "nav", False, 0, None, "goal rejected", "rejected"),
    ]
    # roslibpy reads `status` of every action_result, failures included.
    assert json.loads(frames[4])["status"] == 0 and json.loads(frames[4])["result"] is False


@pytest.mark.parametrize(
    ("frame", "fragment"),
    [
        ('{"op":"service_response","service":"/x","values":{}}', "'id'"),
        ('{"op":"service_response","id":true,"service":"/x","values":{}}', "'id'"),
        ('{"op":"service_response","id":1,"values":{}}', "'service'"),
        ('{"op":"service_response","id":1,"service":"/x","values":[1],"result":true}', "not an object"),
        ('{"op":"service_response","id":1,"service":"/x","values":{},"result":"yes"}', "'result'"),
        ('{"op":"action_feedback","id":1,"action":"a","values":"x"}', "not an object"),
        ('{"op":"action_result","id":1,"action":"a","values":{},"status":9,"result":true}', "status"),
        ('{"op":"action_result","id":1,"action":"a","values":{},"status":"4","result":true}', "status"),
    ],
)
def test_malformed_call_frames_from_the_server_are_protocol_errors(frame: str, fragment: str) -> None:
    with pytest.raises(ProtocolError, match=fragment):
        parse_server_frame(frame)
