"""Generic ROS message ⇄ JSON conversion with rosbridge's conventions."""

from __future__ import annotations

import array
import json
import math

import pytest
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance, Interruption
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import ByteMultiArray, Float64

from by_your_command.ros.convert import ConversionError, from_dict, message_class, to_dict

pytestmark = pytest.mark.unit


def test_nested_header_time_and_base64_bytes() -> None:
    image = Image(width=2, height=1, encoding="rgb8", step=6)
    image.header.stamp.sec, image.header.stamp.nanosec, image.header.frame_id = 5, 7, "cam"
    image.data = array.array("B", [1, 2, 3, 4, 5, 255])
    data = to_dict(image)
    assert data["header"] == {"stamp": {"sec": 5, "nanosec": 7}, "frame_id": "cam"}
    assert data["data"] == "AQIDBAX/"
    assert from_dict(Image, json.loads(json.dumps(data))) == image


def test_audio_arrays_are_integer_lists_and_round_trip() -> None:
    utterance = AudioDataUtterance(utterance_id=2**63 + 1, chunk_sequence=3, sample_rate=16000, channels=1)
    utterance.int16_data = array.array("h", [0, -32768, 32767])
    data = to_dict(utterance)
    assert data["int16_data"] == [0, -32768, 32767] and data["uint8_data"] == ""
    assert from_dict(AudioDataUtterance, data) == utterance
    chunk = from_dict(AudioChunk, {"sample_rate": 24000, "channels": 1, "data": [1, 2, 3]})
    assert list(chunk.data) == [1, 2, 3] and chunk.header.frame_id == ""  # absent fields keep defaults


def test_octets_and_sequences_of_messages() -> None:
    array_msg = from_dict(ByteMultiArray, {"data": "AQID"})
    assert to_dict(array_msg)["data"] == "AQID"
    diag = from_dict(
        DiagnosticArray, {"status": [{"name": "x", "level": 2, "values": [{"key": "k", "value": "v"}]}]}
    )
    assert diag.status[0].level == b"\x02" and diag.status[0].values[0].key == "k"
    assert to_dict(diag)["status"][0]["level"] == 2


def test_fixed_size_arrays_keep_their_length() -> None:
    info = CameraInfo()
    info.k[0] = 1.5
    restored = from_dict(CameraInfo, json.loads(json.dumps(to_dict(info))))
    assert restored == info and restored.k[0] == 1.5
    with pytest.raises(ConversionError, match="exactly 9 elements"):
        from_dict(CameraInfo, {"k": [1.0]})


def test_non_finite_floats_become_null() -> None:
    assert to_dict(Float64(data=math.inf)) == {"data": None}
    assert math.isnan(from_dict(Float64, {"data": None}).data)


def test_compressed_image_accepts_base64_or_list() -> None:
    assert bytes(from_dict(CompressedImage, {"format": "jpeg", "data": "/9j/"}).data) == b"\xff\xd8\xff"
    assert bytes(from_dict(CompressedImage, {"data": [255, 216]}).data) == b"\xff\xd8"


@pytest.mark.parametrize(
    ("cls", "data", "fragment"),
    [
        (Twist, {"linear": {"x": "fast"}}, "linear.x: expected a number"),
        (Twist, {"linear": 1}, "linear: expected an object"),
        (Twist, {"speed": 1}, "unknown field"),
        (AudioChunk, {"channels": 256}, "out of range for uint8"),
        (AudioChunk, {"data": [1, 40000]}, r"data\[1\]: 40000 is out of range for int16"),
        (AudioChunk, {"stream_id": 5}, "expected a string"),
        (AudioChunk, {"sample_rate": True}, "expected an integer"),
        (AudioDataUtterance, {"is_utterance_end": 1}, "expected true/false"),
        (CompressedImage, {"data": "not base64!"}, "not valid base64"),
        (CompressedImage, {"data": 5}, "expected a list or base64"),
    ],
)
def test_bad_inbound_fields_name_the_field(cls: type, data: dict[str, object], fragment: str) -> None:
    with pytest.raises(ConversionError, match=fragment):
        from_dict(cls, data)


def test_message_class_lookup() -> None:
    assert message_class("std_msgs/String").__name__ == "String"
    assert message_class("geometry_msgs/msg/Twist") is Twist
    with pytest.raises(ConversionError, match="not installed"):
        message_class("no_such_pkg/msg/Thing")


def test_shipped_allow_lists_parse_and_name_installed_types() -> None:
    from pathlib import Path

    from by_your_command.bridge.config import load_allow_lists

    shipped = Path(__file__).resolve().parents[2] / "config" / "bridge.yaml"
    allow = load_allow_lists(shipped)
    topics = {rule.topic for rule in allow.subscribe} | {rule.topic for rule in allow.publish}
    assert {
        "prompt_voice",
        "camera_forwarded",
        "response_voice",
        "response_cmd",
        "interruption_signal",
    } <= topics
    for rule in (*allow.subscribe, *allow.publish):
        assert not rule.topic.startswith("/"), "shipped topics must be relative (namespaces move the graph)"
        message_class(rule.type)


def test_interruption_names_what_it_cuts() -> None:
    data = {
        "header": {"stamp": {"sec": 12, "nanosec": 5}, "frame_id": ""},
        "stream_id": "reply-7",
        "reason": "barge_in",
    }
    interruption = from_dict(message_class("by_your_command_msgs/msg/Interruption"), data)
    assert isinstance(interruption, Interruption)
    assert (interruption.stream_id, interruption.reason, interruption.header.stamp.sec) == (
        "reply-7",
        "barge_in",
        12,
    )
    assert to_dict(interruption) == {**data, "action": Interruption.CUT}  # a sender without it cuts
    paused = from_dict(Interruption, {**data, "action": Interruption.PAUSE})
    assert paused.action == Interruption.PAUSE
    with pytest.raises(ConversionError, match="unknown field"):
        from_dict(Interruption, {"data": True})  # the old Bool shape is refused, not half-accepted


def test_shipped_interruption_signal_has_the_interruption_type() -> None:
    from pathlib import Path

    from by_your_command.bridge.config import load_allow_lists

    shipped = load_allow_lists(Path(__file__).resolve().parents[2] / "config" / "bridge.yaml")
    [rule] = [rule for rule in shipped.publish if rule.topic == "interruption_signal"]
    assert rule.type == "by_your_command_msgs/msg/Interruption" and message_class(rule.type) is Interruption


def test_audio_fast_path_keeps_the_exact_checks() -> None:
    samples = list(range(-32768, 32768, 7))
    assert list(from_dict(AudioChunk, {"data": samples}).data) == samples
    for bad, fragment in (
        ([0] * 10 + [32768], r"data\[10\]: 32768 is out of range"),
        ([0, True], r"data\[1\]: expected an integer"),
        ([0, 1.0], r"data\[1\]: expected an integer"),
    ):
        with pytest.raises(ConversionError, match=fragment):
            from_dict(AudioChunk, {"data": bad})


def test_errors_quote_client_values_briefly() -> None:
    huge = "x" * 100_000
    for data in ({"sample_rate": huge}, {"stream_id": [huge] * 10}, {huge: 1}, {"data": [huge]}):
        with pytest.raises(ConversionError) as error:
            from_dict(AudioChunk, data)
        assert len(str(error.value)) < 200, str(error.value)[:300]
