"""Hostile rosbridge frames against the pure parser, the JSON → ROS converter and BridgeCore.

Fast targets, many inputs: every frame is either a typed request or a ProtocolError (never another
exception); every frame BridgeCore receives gets at most one short status reply, a parse failure
exactly one `bad_request`, and no `internal_error`; a well-behaved request works afterwards.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from bridge_fakes import FakeGraph
from byc_testing import REPO_ROOT
from call_frames import call_frames
from fuzzing import TALLY, fuzz_settings, hostile_frames
from hypothesis import given
from hypothesis import strategies as st
from ros_messages import ALLOW, PUBLISH_CLASSES, message_dicts, publish_frames

from by_your_command.bridge.calls import ActionRule, CallOutcome, ServiceRule
from by_your_command.bridge.config import BridgeParams, TopicRule
from by_your_command.bridge.core import MAX_STATUS_MESSAGE_CHARS, BridgeCore, PublishError
from by_your_command.bridge.protocol import (
    MAX_CALL_TIMEOUT_S,
    MAX_ID_INT,
    MAX_OPTION_VALUE,
    MAX_TOPIC_CHARS,
    Advertise,
    CallService,
    CancelActionGoal,
    ProtocolError,
    Publish,
    SendActionGoal,
    Subscribe,
    encode_request,
    parse_request,
)
from by_your_command.ros.convert import ConversionError, from_dict, message_class

pytestmark = [pytest.mark.unit, pytest.mark.timeout(600)]

NAMESPACE = "/fuzz"
SUBSCRIBABLE = [rule.topic for rule in ALLOW.subscribe] + [f"{NAMESPACE}/prompt_text", "no_such_topic"]
PUBLISHABLE = [rule.topic for rule in ALLOW.publish] + [f"{NAMESPACE}/response_cmd", "prompt_voice"]
FRAMES = hostile_frames(SUBSCRIBABLE, PUBLISHABLE)
# Calls and goals: allow-listed for the core target below, plus names that are not.
CALL_ALLOW = replace(
    ALLOW,
    services=(ServiceRule("reset_pose", "std_srvs/srv/Trigger"),),
    actions=(ActionRule("navigate", "nav2_msgs/action/NavigateToPose"),),
)
CALLS = call_frames(
    ["reset_pose", f"{NAMESPACE}/reset_pose", "no_such_service"], ["navigate", "no_such_action"]
)
# What a topic or type may look like once the parser accepted it: nothing else slips through.
STRICT_TOPIC = re.compile(r"/?[A-Za-z~][A-Za-z0-9_/~]*")
STRICT_TYPE = re.compile(r"[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*")
STRICT_SRV = re.compile(r"[A-Za-z][A-Za-z0-9_]*/srv/[A-Za-z][A-Za-z0-9_]*")
STRICT_ACTION = re.compile(r"[A-Za-z][A-Za-z0-9_]*/action/[A-Za-z][A-Za-z0-9_]*")


def request_name(request: Any) -> str:
    if isinstance(request, CallService):
        return request.service
    if isinstance(request, (SendActionGoal, CancelActionGoal)):
        return request.action
    return str(request.topic)


def check_parsed(frame: str | bytes) -> Any:
    """parse_request's contract on any input; returns the request, or None for a ProtocolError."""
    try:
        request = parse_request(frame)
    except ProtocolError as error:
        assert str(error), "a refusal must say why"
        return None
    name = request_name(request)
    assert STRICT_TOPIC.fullmatch(name) and len(name) <= MAX_TOPIC_CHARS, request
    assert request.id is None or isinstance(request.id, (str, int)) and not isinstance(request.id, bool)
    assert not isinstance(request.id, int) or abs(request.id) <= MAX_ID_INT
    if isinstance(request, Advertise):
        assert STRICT_TYPE.fullmatch(request.type), request
    if isinstance(request, Subscribe):
        assert request.type is None or STRICT_TYPE.fullmatch(request.type), request
        assert (
            0 <= request.throttle_rate_ms <= MAX_OPTION_VALUE
            and 0 <= request.queue_length <= MAX_OPTION_VALUE
        )
    if isinstance(request, Publish):
        assert isinstance(request.msg, dict)
    if isinstance(request, (CallService, SendActionGoal, CancelActionGoal)):
        assert request.id is not None, "calls are answered by id: it is required"
    if isinstance(request, CallService):
        assert isinstance(request.args, dict)
        assert request.type is None or STRICT_SRV.fullmatch(request.type), request
        assert request.timeout_s is None or 0 < request.timeout_s <= MAX_CALL_TIMEOUT_S
    if isinstance(request, SendActionGoal):
        assert isinstance(request.args, dict) and isinstance(request.feedback, bool)
        assert STRICT_ACTION.fullmatch(request.action_type), request
    # What we accepted, our own client writes back the same way.
    assert parse_request(encode_request(request)) == request
    return request


@fuzz_settings(short=300, long=40_000)
@given(FRAMES)
def test_any_frame_parses_to_a_request_or_a_protocol_error(frame: str | bytes) -> None:
    with TALLY.input("bridge.parse_request"):
        check_parsed(frame)


@fuzz_settings(short=300, long=20_000)
@given(CALLS)
def test_any_call_frame_parses_to_a_call_or_a_protocol_error(frame: str) -> None:
    with TALLY.input("bridge.parse_request (calls)"):
        check_parsed(frame)


@pytest.mark.parametrize(
    "frame",
    [
        '{"op":"subscribe","topic":"prompt_text\\n"}',
        '{"op":"advertise","topic":"response_text","type":"std_msgs/String\\n"}',
        '{"op":"subscribe","topic":"prompt_text","type":"std_msgs/msg/String\\n"}',
        '{"op":"call_service","id":1,"service":"reset_pose\\n"}',
        '{"op":"call_service","id":1,"service":"reset_pose","type":"std_srvs/Trigger\\n"}',
        '{"op":"send_action_goal","id":1,"action":"navigate","action_type":"a/B\\n"}',
    ],
)
def test_a_trailing_newline_does_not_make_a_name_valid(frame: str) -> None:
    """`$` also matches before a final newline: "prompt_text\\n" used to pass as a valid name."""
    with pytest.raises(ProtocolError, match="invalid"):
        parse_request(frame)


# --- the JSON → ROS converter of the real node, on every publishable type --------------------------

CONVERTER_INPUTS = st.sampled_from(sorted(PUBLISH_CLASSES)).flatmap(
    lambda type_name: st.tuples(st.just(type_name), message_dicts(type_name))
)


@fuzz_settings(short=200, long=10_000)
@given(CONVERTER_INPUTS)
def test_any_message_object_converts_or_is_a_conversion_error(case: tuple[str, dict[str, Any]]) -> None:
    type_name, msg = case
    with TALLY.input("ros.convert.from_dict"):
        try:
            converted = from_dict(PUBLISH_CLASSES[type_name], msg)
        except ConversionError as error:
            assert str(error)
            return
        assert isinstance(converted, PUBLISH_CLASSES[type_name])


# --- BridgeCore with the real converter -------------------------------------------------------------


class ConvertingGraph(FakeGraph):
    """The fake ROS port with the node's real conversion (what `_NodeGraph.convert` does).

    Calls and goals are answered at once, alternately with success and failure (and a goal with
    feedback first), so every outcome path meets hostile ids and names.
    """

    def __init__(self) -> None:
        super().__init__()
        self.outcomes = 0

    def convert(self, rule: TopicRule, msg: dict[str, Any]) -> Any:
        try:
            return from_dict(PUBLISH_CLASSES[rule.type], msg)
        except ConversionError as error:
            raise PublishError(str(error)) from None

    def _outcome(self) -> CallOutcome:
        self.outcomes += 1
        if self.outcomes % 2:
            return CallOutcome(True, '{"ok":true}', status=4)
        return CallOutcome(False, error="no server", code="no_server", status=6)

    def call_service(self, rule: Any, full_name: str, request: Any, timeout_s: float, done: Any) -> None:
        super().call_service(rule, full_name, request, timeout_s, done)
        done(self._outcome())

    def send_goal(self, rule: Any, full_name: str, goal: Any, token: int, feedback: Any, done: Any) -> None:
        super().send_goal(rule, full_name, goal, token, feedback, done)
        feedback('{"left":1.0}')
        done(self._outcome())


def make_core() -> tuple[BridgeCore, ConvertingGraph]:
    # Everything inline (no event loop here); the worker path is exercised by the wire test.
    params = replace(BridgeParams(port=0, max_message_bytes=200_000), inline_convert_bytes=200_000)
    graph = ConvertingGraph()
    return BridgeCore(params, CALL_ALLOW, graph, NAMESPACE), graph


def replies(session: Any) -> list[dict[str, Any]]:
    found = []
    while (text := session.queue.take_nowait()) is not None:
        assert text.isascii()  # json.dumps escapes whatever the client sent
        found.append(json.loads(text))
    return found


SEQUENCES = st.lists(FRAMES | publish_frames() | CALLS, min_size=1, max_size=8)
REPLY_OPS = {"call_service": "service_response", "send_action_goal": "action_result"}


@fuzz_settings(short=150, long=6_000)
@given(SEQUENCES)
def test_core_answers_every_hostile_frame_and_still_serves(frames: list[str | bytes]) -> None:
    core, graph = make_core()
    session = core.open_session("hostile")
    with TALLY.input("bridge.BridgeCore", count=len(frames)):
        for frame in frames:
            rejected_before = session.rejected
            core.handle_frame(session, frame)  # never raises
            everything = replies(session)
            answers = [r for r in everything if r["op"] == "status"]
            assert len(answers) == session.rejected - rejected_before <= 1
            for answer in answers:
                assert answer["level"] in ("error", "warning") and answer["code"] != "internal_error", answer
                assert len(answer["msg"]) <= MAX_STATUS_MESSAGE_CHARS + 1
            request = check_parsed(frame)
            if isinstance(request, (CallService, SendActionGoal)):
                # Exactly one answer to the call, refused or not, with the id the client sent.
                op = REPLY_OPS["call_service" if isinstance(request, CallService) else "send_action_goal"]
                finals = [r for r in everything if r["op"] == op]
                assert [(r["id"], type(r["result"])) for r in finals] == [(request.id, bool)], everything
                assert finals[0]["result"] or isinstance(finals[0]["values"], str)
            if request is None:
                too_large = len(frame if isinstance(frame, bytes) else frame.encode("utf-8", "surrogatepass"))
                expected = "too_large" if too_large > core.params.max_message_bytes else "bad_request"
                assert [a["code"] for a in answers] == [expected], (frame[:200], answers)
        assert core.totals().internal_errors == 0
        for full_topic, message in graph.published:
            rule = core._publishable[full_topic]
            assert isinstance(message, PUBLISH_CLASSES[rule.type])
        # A well-behaved client on the same bridge is served as if nothing happened.
        polite = core.open_session("polite")
        core.handle_frame(polite, '{"op":"subscribe","topic":"prompt_text","id":1}')
        core.deliver(f"{NAMESPACE}/prompt_text", '{"data":"still here"}')
        assert [r.get("msg") for r in replies(polite)] == [{"data": "still here"}]
        published = len(graph.published)
        core.handle_frame(polite, '{"op":"publish","topic":"response_cmd","msg":{"data":"stop"}}')
        assert replies(polite) == [] and len(graph.published) == published + 1


def test_out_of_range_fields_are_conversion_errors() -> None:
    """Values the fuzzer tried first, as fixed examples (kept fast and readable)."""
    audio = PUBLISH_CLASSES["by_your_command_msgs/msg/AudioChunk"]
    for msg in (
        {"data": [32768]},
        {"data": [True]},
        {"sample_rate": -1},
        {"header": {"stamp": {"sec": 2**40}}},
        {"header": {"frame_id": 5}},
        {"channels": 256},
    ):
        with pytest.raises(ConversionError):
            from_dict(audio, msg)
    assert math.isnan(from_dict(message_class("std_msgs/msg/Float32"), {"data": None}).data)


def test_shipped_allow_list_is_what_the_fuzzer_aims_at() -> None:
    """The fuzzer targets the real allow-list: a renamed topic must not silently empty a target."""
    assert Path(REPO_ROOT / "by_your_command" / "config" / "bridge.yaml").is_file()
    assert {"response_cmd", "response_voice", "interruption_signal"} <= {r.topic for r in ALLOW.publish}
