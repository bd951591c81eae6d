"""The `gpt_live` provider's settings (the `provider:` section of an agent config)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from by_your_command.agents.robot_tool import TOOL_NAME


@dataclass(frozen=True)
class GptLiveConfig:
    model: str = "gpt-live-1"
    voice: str = "marin"  # fixed for the session's life
    # One PCM16 format both ways (the session's audio.format): the runtime resamples the microphone
    # to it and the reply audio comes at it. 24 kHz keeps the voice's quality.
    sample_rate: Literal[16000, 24000] = 24000
    # The input is one stream in real time: between utterances (our VAD sends speech only) silence
    # is appended every `input_tick_ms`, so the model hears the user stop and time pass.
    input_tick_ms: int = 20  # the tick adds up to this to when the model hears the user stop
    max_catch_up_ms: int = 1000  # a stalled loop skips what it is behind beyond this (never a burst)
    # Output deltas carry no reply id and no event ends a reply: one ends after this much quiet.
    # Above the delta cadence (100 ms) plus network jitter; it delays only the reply's bookkeeping.
    reply_end_gap_ms: int = 600
    # The model streams its voice at about real time: once the user spoke over it, output quiet
    # this long means it yielded, and the player cuts what it still holds of the reply.
    yield_gap_ms: int = 250
    delegation_tool: str = TOOL_NAME  # the tool a client delegation calls (see events.py)
    acknowledgement_delay_ms: int | None = None  # spoken "one moment" after a delegation; None: server's
    safety_identifier: str = ""  # a stable id of the end user for OpenAI's abuse monitoring; "" none
    # session.start input: at most 128 messages and about 8,192 tokens (documented).
    max_history_messages: int = 128
    max_history_chars: int = 24_000
    max_append_chars: int = 2_000  # one instructions/thinking/commentary append (about 500 tokens)
    closed_wait_s: float = 2.0  # close waits this long for session.closed (the final usage)
    max_session_s: float = 3600.0  # the runtime rotates before it (the server's limit is not published)
    base_url: str = ""  # "" = the SDK's OPENAI_BASE_URL or api.openai.com
    websocket_base_url: str = ""  # wins over base_url; must end in /v1 (the SDK appends /live/sessions)
    extra_headers: tuple[tuple[str, str], ...] = ()  # e.g. OpenAI-Project, proxy auth
    event_queue_size: int = 1024  # events the runtime has not read yet; the socket waits beyond it

    def __post_init__(self) -> None:
        if not self.model or not self.voice or not self.delegation_tool:
            raise ValueError("model, voice and delegation_tool must not be empty")
        if not 10 <= self.input_tick_ms <= 1_000:
            raise ValueError("input_tick_ms must be within 10..1000")
        if not self.input_tick_ms <= self.max_catch_up_ms <= 10_000:
            raise ValueError("max_catch_up_ms must be within input_tick_ms..10000")
        if not 50 <= self.reply_end_gap_ms <= 10_000:
            raise ValueError("reply_end_gap_ms must be within 50..10000")
        if not 50 <= self.yield_gap_ms <= 10_000:  # reply_end_gap_ms if larger: never longer than it
            raise ValueError("yield_gap_ms must be within 50..10000")
        if self.acknowledgement_delay_ms is not None and not 0 <= self.acknowledgement_delay_ms <= 60_000:
            raise ValueError("acknowledgement_delay_ms must be within 0..60000")
        if not 0 <= self.max_history_messages <= 128 or self.max_history_chars < 0:
            raise ValueError("max_history_messages must be within 0..128 and max_history_chars >= 0")
        if self.max_append_chars < 16 or self.event_queue_size < 1:
            raise ValueError("max_append_chars must be >= 16 and event_queue_size >= 1")
        for name in ("closed_wait_s", "max_session_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0")
