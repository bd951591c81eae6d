"""Which camera frame the model sees (agents/frames.py): the latest kept frame, once per session,
only while fresh, only if taken after the question's cut-off, one per question. (Through the
runtime: test_turns.py; through the real graph: test_gemini_features_graph.py.)"""

from __future__ import annotations

import io

import pytest
from PIL import Image

from by_your_command.agents.detections import FrameInfo
from by_your_command.agents.frames import FrameChoice
from by_your_command.agents.inputs import CameraFrame

pytestmark = pytest.mark.unit


def jpeg(width: int, height: int) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (width, height)).save(buffer, format="JPEG")
    return buffer.getvalue()


FRAME = CameraFrame(jpeg(64, 48), stamp=12.5, frame_id="camera")
LATER = CameraFrame(jpeg(32, 24), stamp=13.0, frame_id="camera")


def test_a_kept_frame_goes_once_per_session_and_the_latest_replaces_an_unsent_one() -> None:
    frames = FrameChoice(max_age_s=2.0)
    assert frames.take(now=0.0) is None  # nothing kept
    frames.keep(FRAME, now=1.0)
    frames.keep(LATER, now=1.1)
    assert frames.take(now=1.2) is LATER
    assert frames.take(now=1.3) is None  # sent already
    frames.new_session()
    assert frames.take(now=1.4) is LATER  # a new session has seen nothing


def test_a_frame_from_before_the_cut_off_waits_and_a_stale_one_is_used_up() -> None:
    frames = FrameChoice(max_age_s=2.0)
    frames.keep(FRAME, now=1.0)
    assert frames.take(now=1.5, since=1.0) is None  # from before the question: not this one's
    assert frames.take(now=3.5) is None  # 2.5 s old: too old to show
    frames.new_session()
    assert frames.take(now=3.6) is None  # and never later either: it was used up
    assert frames.shown() is None


def test_one_frame_per_question_and_the_shown_frame_has_its_pixel_size() -> None:
    frames = FrameChoice(max_age_s=2.0)
    assert frames.give_to(3, now=0.5) is None
    assert frames.asked_turn == 0  # no frame: the question may still get one
    frames.keep(FRAME, now=1.0)
    assert frames.give_to(3, now=1.1) is FRAME
    assert frames.asked_turn == 3
    assert frames.shown() == FrameInfo(64, 48, 12.5, "camera")
    unreadable = CameraFrame(b"not a jpeg")
    frames.keep(unreadable, now=1.2)
    assert frames.take(now=1.3) is unreadable
    assert frames.shown() == FrameInfo(0, 0)
