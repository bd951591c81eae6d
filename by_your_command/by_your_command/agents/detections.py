"""Gemini's native object detections in a model's text → typed boxes, and the messages that carry them.

Asked to find things, Gemini answers with a JSON list (often inside ```json fences):

    [{"box_2d": [ymin, xmin, ymax, xmax], "label": "cup"}, ...]

with coordinates on 0–1000 of the image it was shown. `extract` finds such JSON in any text and
returns the detections and the text without them, so a command agent never routes boxes to the
command processor. Every byte is untrusted: the text, the JSON values tried and the detections are
bounded, coordinates are clamped to 0–1000, an empty box (min >= max) or a non-finite number refuses
its entry (counted, never guessed at). Pure: no I/O, no clock.

`detections_json` is the `detections` topic's JSON (docs/gemini.md), in pixels of the frame the
model was shown; `detection2d_array` the same as a vision_msgs (>= 4.0, Humble) Detection2DArray dict.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any

SCALE = 1000.0  # Gemini's box coordinates are on 0..1000 of the image's height and width
MAX_TEXT_CHARS = 65_536  # longer texts are not parsed (their detections are refused)
MAX_DETECTIONS = 100  # per text; the rest are refused
MAX_LABEL_CHARS = 100
MAX_ATTEMPTS = 16  # JSON values tried per text (raw_decode is linear: bounded work on hostile text)
MARKER = "box_2d"

_FENCE = re.compile(r"```[ \t]*(?:json|JSON)?[ \t]*\r?\n?(.*?)```", re.DOTALL)
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
_SPACES = re.compile(r"[ \t]{2,}")
_DECODER = json.JSONDecoder()


@dataclass(frozen=True)
class Detection:
    label: str
    box_2d: tuple[float, float, float, float]  # ymin, xmin, ymax, xmax on 0..1000, clamped
    score: float | None = None  # Gemini gives none; a `score`/`confidence` in 0..1 is kept


@dataclass(frozen=True)
class Extraction:
    detections: tuple[Detection, ...] = ()
    text: str = ""  # the text without the detection JSON
    refused: int = 0  # entries (or whole texts) that held no usable detection
    unparsed: bool = False  # the text still mentions box_2d: detection JSON we could not read

    @property
    def found(self) -> bool:
        return bool(self.detections) or self.refused > 0 or self.unparsed


@dataclass(frozen=True)
class FrameInfo:
    """The camera frame the model was shown: its pixel size and ROS header."""

    width: int
    height: int
    stamp: float = 0.0  # the frame's header stamp, seconds
    frame_id: str = ""


def extract(text: str) -> Extraction:
    """The detections in `text` and the text without them (`Extraction.found` False: none there)."""
    if MARKER not in text:
        return Extraction(text=text)
    if len(text) > MAX_TEXT_CHARS:
        return Extraction(refused=1, unparsed=True)
    spans: list[tuple[int, int]] = []
    entries: list[Any] = []
    for fence in _FENCE.finditer(text):
        value = _json_value(fence.group(1).strip())
        if value is not _NOTHING and _mentions_marker(value):
            spans.append(fence.span())
            entries += _as_entries(value)
    rest = _cut(text, spans)
    bare, rest = _bare_json(rest)
    entries += bare
    detections: list[Detection] = []
    refused = 0
    for entry in entries:
        detection = _detection(entry)
        if detection is None or len(detections) >= MAX_DETECTIONS:
            refused += 1
        else:
            detections.append(detection)
    rest = _tidy(rest)
    return Extraction(tuple(detections), rest, refused, MARKER in rest)


# --- finding the JSON ----------------------------------------------------------------------------

_NOTHING = object()


def _json_value(text: str) -> Any:
    try:
        return json.loads(text)
    except (ValueError, RecursionError):
        return _NOTHING


def _mentions_marker(value: Any) -> bool:
    return any(isinstance(entry, dict) and MARKER in entry for entry in _as_entries(value))


def _as_entries(value: Any) -> list[Any]:
    if isinstance(value, dict):
        return [value]
    return list(value) if isinstance(value, list) else []


def _bare_json(text: str) -> tuple[list[Any], str]:
    """Unfenced detection JSON: the list (or object) that opens nearest before each `box_2d`."""
    entries: list[Any] = []
    spans: list[tuple[int, int]] = []
    position = 0
    for _ in range(MAX_ATTEMPTS):
        marker = text.find(MARKER, position)
        if marker < 0:
            break
        found = None
        for opener in (text.rfind("[", position, marker), text.rfind("{", position, marker)):
            if opener < 0:
                continue
            try:
                value, end = _DECODER.raw_decode(text, opener)
            except (ValueError, RecursionError):
                continue
            if end > marker and _mentions_marker(value):
                found = (opener, end, value)
                break
        if found is None:
            position = marker + len(MARKER)
            continue
        start, end, value = found
        spans.append((start, end))
        entries += _as_entries(value)
        position = end
    return entries, _cut(text, spans)


def _cut(text: str, spans: list[tuple[int, int]]) -> str:
    pieces, last = [], 0
    for start, end in sorted(spans):
        pieces.append(text[last:start])
        last = end
    pieces.append(text[last:])
    return " ".join(piece.strip() for piece in pieces if piece.strip())


def _tidy(text: str) -> str:
    return _SPACES.sub(" ", text).strip()


# --- one entry -----------------------------------------------------------------------------------


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def _detection(entry: Any) -> Detection | None:
    if not isinstance(entry, dict):
        return None
    box = entry.get(MARKER)
    label = entry.get("label")
    if not isinstance(box, list) or len(box) != 4 or not isinstance(label, str):
        return None
    numbers = [_number(value) for value in box]
    if any(number is None for number in numbers):
        return None
    ymin, xmin, ymax, xmax = (min(SCALE, max(0.0, number)) for number in numbers if number is not None)
    if not (ymin < ymax and xmin < xmax):
        return None
    label = _CONTROL.sub(" ", label).strip()[:MAX_LABEL_CHARS].strip()
    if not label:
        return None
    score = _number(entry.get("score", entry.get("confidence")))
    return Detection(
        label, (ymin, xmin, ymax, xmax), score if score is not None and 0 <= score <= 1 else None
    )


# --- messages ------------------------------------------------------------------------------------


def pixel_box(detection: Detection, frame: FrameInfo) -> list[float]:
    """[x_min, y_min, x_max, y_max] in pixels of `frame`."""
    ymin, xmin, ymax, xmax = detection.box_2d
    sx, sy = frame.width / SCALE, frame.height / SCALE
    return [round(xmin * sx, 2), round(ymin * sy, 2), round(xmax * sx, 2), round(ymax * sy, 2)]


def detections_json(
    detections: tuple[Detection, ...], frame: FrameInfo | None, agent_id: str
) -> dict[str, Any]:
    """The `detections` topic's JSON object (schema in docs/gemini.md). Without a known frame the
    pixel boxes are null and width/height 0: the model's 0..1000 boxes are still given."""
    sized = frame is not None and frame.width > 0 and frame.height > 0
    return {
        "stamp": frame.stamp if frame is not None else 0.0,
        "frame_id": frame.frame_id if frame is not None else "",
        "width": frame.width if sized and frame is not None else 0,
        "height": frame.height if sized and frame is not None else 0,
        "agent_id": agent_id,
        "detections": [
            {
                "label": detection.label,
                "box": pixel_box(detection, frame) if sized and frame is not None else None,
                "box_2d": list(detection.box_2d),
                "score": detection.score,
            }
            for detection in detections
        ],
    }


def _ros_header(frame: FrameInfo | None) -> dict[str, Any]:
    stamp = frame.stamp if frame is not None else 0.0
    sec = int(stamp)
    nanosec = min(999_999_999, int(round((stamp - sec) * 1e9)))
    return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame.frame_id if frame else ""}


def detection2d_array(detections: tuple[Detection, ...], frame: FrameInfo) -> dict[str, Any]:
    """vision_msgs/msg/Detection2DArray (vision_msgs >= 4.0: Pose2D has `position`) as a dict for the
    bridge. Gemini gives no score: `score` 0.0 then means unknown, not unlikely."""
    header = _ros_header(frame)
    out = []
    for detection in detections:
        x_min, y_min, x_max, y_max = pixel_box(detection, frame)
        out.append(
            {
                "header": header,
                "results": [{"hypothesis": {"class_id": detection.label, "score": detection.score or 0.0}}],
                "bbox": {
                    "center": {
                        "position": {"x": (x_min + x_max) / 2, "y": (y_min + y_max) / 2},
                        "theta": 0.0,
                    },
                    "size_x": x_max - x_min,
                    "size_y": y_max - y_min,
                },
                "id": "",
            }
        )
    return {"header": header, "detections": out}
