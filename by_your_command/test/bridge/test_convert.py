"""Generic ROS message ⇄ JSON conversion with rosbridge's conventions."""

from __future__ import annotations

import array
import json
import math

import pytest
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance
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
