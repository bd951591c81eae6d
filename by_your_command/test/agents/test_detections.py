"""Gemini's box_2d detections in model text: parsing hostile text, pixels, the topic payloads."""

from __future__ import annotations

import io
import json
import sys
import types
from collections.abc import Iterator
from typing import Any

import pytest
from PIL import Image

from by_your_command.agents.detections import (
    MAX_DETECTIONS,
    MAX_LABEL_CHARS,
    MAX_TEXT_CHARS,
    Detection,
    FrameInfo,
    detection2d_array,
    detections_json,
    extract,
)
from by_your_command.agents.frame_size import jpeg_size

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

CUP = '{"box_2d": [100, 200, 500, 600], "label": "cup"}'
PERSON = '{"box_2d": [0, 0, 1000, 250], "label": "person"}'


def labels(text: str) -> list[str]:
    return [d.label for d in extract(text).detections]


# --- finding the JSON --------------------------------------------------------------------------


def test_text_without_boxes_passes_untouched() -> None:
    found = extract("pan@left, lookup [twice]")
    assert not found.found and found.text == "pan@left, lookup [twice]"


def test_a_bare_list_is_parsed_and_removed_from_the_text() -> None:
    found = extract(f"Here you go: [{CUP}, {PERSON}] lookup")
    assert found.detections == (
        Detection("cup", (100.0, 200.0, 500.0, 600.0)),
        Detection("person", (0.0, 0.0, 1000.0, 250.0)),
    )
    assert found.text == "Here you go: lookup" and found.refused == 0 and not found.unparsed


def test_json_fences_and_single_objects_are_accepted() -> None:
    fenced = extract(f"Sure.\n```json\n[{CUP}]\n```\nDone.")
    assert [d.label for d in fenced.detections] == ["cup"] and fenced.text == "Sure. Done."
    assert labels(f"```\n[{PERSON}]\n```") == ["person"]  # a fence without a language
    assert labels(f"found {CUP} and {PERSON}") == ["cup", "person"]  # objects, no list
    assert labels(f"[note] {CUP}") == ["cup"]  # prose brackets before the JSON


def test_coordinates_are_clamped_and_empty_boxes_refused() -> None:
    found = extract(
        '[{"box_2d": [-50, 10, 1200, 990.5], "label": "big"},'
        ' {"box_2d": [500, 100, 400, 200], "label": "upside down"},'
        ' {"box_2d": [100, 300, 200, 300], "label": "zero width"},'
        ' {"box_2d": [1100, 0, 1200, 50], "label": "outside"}]'
    )
    assert found.detections == (Detection("big", (0.0, 10.0, 1000.0, 990.5)),)
    assert found.refused == 3


@pytest.mark.parametrize(
    "entry",
    [
        '{"box_2d": [NaN, 1, 2, 3], "label": "nan"}',
        '{"box_2d": [Infinity, 1, 2, 3], "label": "inf"}',
        '{"box_2d": [1e999, 1, 2, 3], "label": "overflow"}',
        '{"box_2d": [true, 1, 2, 3], "label": "bool"}',
        '{"box_2d": ["1", 1, 2, 3], "label": "string"}',
        '{"box_2d": [1, 2, 3], "label": "three"}',
        '{"box_2d": [1, 2, 3, 4, 5], "label": "five"}',
        '{"box_2d": {"y": 1}, "label": "object"}',
        '{"box_2d": [1, 2, 300, 400]}',
        '{"box_2d": [1, 2, 300, 400], "label": 7}',
        '{"box_2d": [1, 2, 300, 400], "label": " \\u0000\\n "}',
    ],
)
def test_bad_entries_are_refused_and_counted(entry: str) -> None:
    found = extract(f"[{entry}, {CUP}]")
    assert [d.label for d in found.detections] == ["cup"] and found.refused == 1


def test_labels_are_cleaned_and_bounded_and_scores_kept_only_in_range() -> None:
    long = "x" * (MAX_LABEL_CHARS + 50)
    found = extract(
        "["
        '{"box_2d": [1, 2, 300, 400], "label": "red\\u0000\\ncup", "score": 0.75},'
        f'{{"box_2d": [1, 2, 300, 400], "label": "{long}", "confidence": 2.0}}'
        "]"
    )
    assert [(d.label, d.score) for d in found.detections] == [
        ("red  cup", 0.75),
        ("x" * MAX_LABEL_CHARS, None),
    ]


def test_hostile_sizes_are_bounded() -> None:
    many = ", ".join([CUP] * (MAX_DETECTIONS + 5))
    found = extract(f"[{many}]")
    assert len(found.detections) == MAX_DETECTIONS and found.refused == 5

    huge = extract("box_2d " + "x" * MAX_TEXT_CHARS)
    assert huge.detections == () and huge.unparsed and huge.text == ""

    deep = extract("[" * 50_000 + '"box_2d"' + "]" * 50_000)  # the JSON parser's recursion limit
    assert deep.detections == () and deep.unparsed


def test_box_2d_that_cannot_be_read_is_reported_unparsed() -> None:
    found = extract('I think [{"box_2d": [1, 2, 3, 4], "label": "cup"')  # cut off mid-JSON
    assert found.detections == () and found.unparsed and found.found


# --- pixels and payloads -----------------------------------------------------------------------

FRAME = FrameInfo(640, 480, 1_800_000_000.25, "camera_optical")


def test_json_payload_has_pixel_boxes_of_the_frame_shown() -> None:
    found = extract(f"[{CUP}]")
    payload = detections_json(found.detections, FRAME, "command")
    assert payload == {
        "stamp": 1_800_000_000.25,
        "frame_id": "camera_optical",
        "width": 640,
        "height": 480,
        "agent_id": "command",
        "detections": [
            # box_2d [ymin 100, xmin 200, ymax 500, xmax 600] on 0..1000 of 640 x 480
            {
                "label": "cup",
                "box": [128.0, 48.0, 384.0, 240.0],
                "box_2d": [100.0, 200.0, 500.0, 600.0],
                "score": None,
            }
        ],
    }
    assert json.loads(json.dumps(payload)) == payload  # plain JSON, no NaN


def test_json_payload_without_a_frame_keeps_the_models_boxes_only() -> None:
    payload = detections_json(extract(f"[{CUP}]").detections, None, "a")
    assert (payload["width"], payload["height"], payload["stamp"], payload["frame_id"]) == (0, 0, 0.0, "")
    assert payload["detections"][0]["box"] is None and payload["detections"][0]["box_2d"] == [
        100.0,
        200.0,
        500.0,
        600.0,
    ]


# vision_msgs 4.x (ROS 2 Humble and later; github.com/ros-perception/vision_msgs, msg/*.msg):
# Pose2D became {position: Point2D, theta} in 4.0; ObjectHypothesisWithPose = {hypothesis, pose}.
_VISION_MSGS = {
    "Detection2DArray": {"header": "std_msgs/Header", "detections": "sequence<vision_msgs/Detection2D>"},
    "Detection2D": {
        "header": "std_msgs/Header",
        "results": "sequence<vision_msgs/ObjectHypothesisWithPose>",
        "bbox": "vision_msgs/BoundingBox2D",
        "id": "string",
    },
    "ObjectHypothesisWithPose": {
        "hypothesis": "vision_msgs/ObjectHypothesis",
        "pose": "geometry_msgs/PoseWithCovariance",
    },
    "ObjectHypothesis": {"class_id": "string", "score": "double"},
    "BoundingBox2D": {"center": "vision_msgs/Pose2D", "size_x": "double", "size_y": "double"},
    "Pose2D": {"position": "vision_msgs/Point2D", "theta": "double"},
    "Point2D": {"x": "double", "y": "double"},
}


@pytest.fixture
def vision_msgs() -> Iterator[types.ModuleType]:
    """Stand-in classes with vision_msgs 4.x's fields (the package is not installed here), so the
    bridge's own converter checks every field name and type of the payload."""
    module = types.ModuleType("vision_msgs.msg")
    for name, fields in _VISION_MSGS.items():

        def init(self: Any, _fields: dict[str, str] = fields) -> None:
            for field in _fields:
                setattr(self, field, None)

        cls = type(
            name, (), {"__init__": init, "get_fields_and_field_types": classmethod(lambda c, f=fields: f)}
        )
        setattr(module, name, cls)
    package = types.ModuleType("vision_msgs")
    package.msg = module  # type: ignore[attr-defined]
    saved = {name: sys.modules.get(name) for name in ("vision_msgs", "vision_msgs.msg")}
    sys.modules.update({"vision_msgs": package, "vision_msgs.msg": module})
    yield module
    for name, old in saved.items():
        if old is None:
            sys.modules.pop(name, None)
        else:
            sys.modules[name] = old


def test_detection2d_array_matches_vision_msgs_4(vision_msgs: types.ModuleType) -> None:
    from by_your_command.ros.convert import from_dict

    found = extract('[{"box_2d": [100, 200, 500, 600], "label": "cup", "score": 0.5}]')
    payload = detection2d_array(found.detections, FRAME)
    msg = from_dict(vision_msgs.Detection2DArray, payload)
    assert msg.header.frame_id == "camera_optical" and msg.header.stamp.nanosec == 250_000_000
    [detection] = msg.detections
    assert detection.results[0].hypothesis.class_id == "cup" and detection.results[0].hypothesis.score == 0.5
    box = detection.bbox
    assert (box.center.position.x, box.center.position.y, box.size_x, box.size_y) == (
        256.0,
        144.0,
        256.0,
        192.0,
    )


# --- frame size --------------------------------------------------------------------------------


def test_jpeg_size_reads_the_header_and_refuses_anything_else() -> None:
    buffer = io.BytesIO()
    Image.new("RGB", (64, 48)).save(buffer, format="JPEG")
    assert jpeg_size(buffer.getvalue()) == (64, 48)
    png = io.BytesIO()
    Image.new("RGB", (4, 4)).save(png, format="PNG")
    assert jpeg_size(png.getvalue()) is None
    assert jpeg_size(b"\xff\xd8not really") is None and jpeg_size(b"") is None
