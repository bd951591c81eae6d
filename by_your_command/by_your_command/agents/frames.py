"""Which camera frame the model sees, and when: the latest frame is kept (it never opens a session),
goes at most once per session, only while fresh, and only with the question it belongs to — one
frame per question, so a long question bills one image. The runtime owns it and sends what it
hands out; the last frame shown gives detections their pixel size."""

from __future__ import annotations

from by_your_command.agents.detections import FrameInfo
from by_your_command.agents.frame_size import jpeg_size
from by_your_command.agents.inputs import CameraFrame


class FrameChoice:
    def __init__(self, max_age_s: float) -> None:
        self._max_age_s = max_age_s
        self._kept: CameraFrame | None = None
        self._kept_at = 0.0
        self._sent = True  # nothing kept: nothing to send
        self.asked_turn = 0  # the voice turn that got its frame (one per question)
        self._shown: CameraFrame | None = None  # the last frame sent to the model
        self._shown_info: FrameInfo | None = None

    def keep(self, frame: CameraFrame, now: float) -> None:
        """A new frame from the camera, kept for the next turn (replacing an unsent one)."""
        self._kept, self._kept_at, self._sent = frame, now, False

    def new_session(self) -> None:
        """A new session has seen no frame: the kept one may go again."""
        self._sent = self._kept is None

    def take(self, now: float, since: float = float("-inf")) -> CameraFrame | None:
        """The kept frame to send now, if unsent, taken after `since` and fresh. A stale one is
        used up too: it never goes later."""
        frame = self._kept
        if frame is None or self._sent or self._kept_at <= since:
            return None
        self._sent = True
        if now - self._kept_at > self._max_age_s:
            return None
        self._shown, self._shown_info = frame, None
        return frame

    def give_to(self, turn_number: int, now: float, since: float = float("-inf")) -> CameraFrame | None:
        """`take` for the question `turn_number`; once it got one, the question is answered."""
        frame = self.take(now, since)
        if frame is not None:
            self.asked_turn = turn_number
        return frame

    def shown(self) -> FrameInfo | None:
        """The last frame the model was shown, with its size read from the JPEG (0 x 0: unreadable)."""
        shown = self._shown
        if shown is None:
            return None
        if self._shown_info is None:
            width, height = jpeg_size(shown.jpeg) or (0, 0)
            self._shown_info = FrameInfo(width, height, shown.stamp, shown.frame_id)
        return self._shown_info
