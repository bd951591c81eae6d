"""The demo's live transcript: bridge deliveries in, readable lines out, and a tally for the summary.

Each line is `[  12.3 s] <what>  <detail>`:
  heard      "look up"                      prompt_transcript (what the agent understood)
  robot      "Looking up."                  response_text (what it said)
  command    lookup -> arm_preset: accepted command_status (the command processor's verdict)
  command    "fly away" refused: <reason>
  attention  asleep                         attention_state
  latency    first audio 240 ms, reply done 1310 ms (completed)   agent_metrics, per turn
  session    closed after 12.0 s billed, 3 turns (idle)           agent_metrics, per session
  file       the speech file has been played to its end           file_audio_done
The narrator also decides when a file-driven demo is over (`settled`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from by_your_command.bridge.client_messages import Delivery, Lost, Received
from by_your_command.bridge.config import TopicClass

# topic -> (type, delivery lane) the demo subscribes to through the bridge (config/bridge.yaml).
TOPICS: dict[str, tuple[str, TopicClass]] = {
    "prompt_transcript": ("std_msgs/msg/String", "text"),
    "response_text": ("std_msgs/msg/String", "text"),
    "command_status": ("by_your_command_msgs/msg/CommandVerdict", "command"),
    "attention_state": ("std_msgs/msg/String", "state"),
    "agent_metrics": ("std_msgs/msg/String", "text"),
    "playback_status": ("by_your_command_msgs/msg/PlaybackStatus", "state"),
    "voice_activity": ("std_msgs/msg/Bool", "state"),
    "file_audio_done": ("std_msgs/msg/Bool", "state"),
}


@dataclass
class Tally:
    heard: list[str] = field(default_factory=list)
    replies: list[str] = field(default_factory=list)
    routed: list[tuple[str, str]] = field(default_factory=list)  # (command, topic)
    refused: list[tuple[str, str]] = field(default_factory=list)  # (what was said, why)
    attention: list[str] = field(default_factory=list)
    turns: int = 0
    lost: int = 0


def _text(value: Any, limit: int = 300) -> str:
    text = " ".join(str(value).split())
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _ms(value: Any) -> str:
    return f"{value:.0f} ms" if isinstance(value, (int, float)) and not isinstance(value, bool) else "-"


class Narrator:
    def __init__(self, namespace: str = "/", started_at: float = 0.0) -> None:
        self.tally = Tally()
        self.file_done = False
        self._prefix = namespace.rstrip("/") + "/"
        self._started = started_at
        self._voice_active = False
        self._disconnected = False
        self._pending_streams: set[str] = set()  # replies the player has not finished (or cut)
        self.last_activity = started_at

    # -- lines ----------------------------------------------------------------------------------

    def feed(self, delivery: Delivery) -> list[str]:
        """The transcript lines for one delivery (often none: state that changes nothing)."""
        if not isinstance(delivery, (Received, Lost)):
            return []  # replies to service calls and goals: the demo makes none
        at = delivery.received_at
        if isinstance(delivery, Lost):
            if delivery.count is None:  # the connection dropped: one line for all topics
                if self._disconnected:
                    return []
                self._disconnected = True
                self.tally.lost += 1
                return [self._line(at, "lost", f"messages in flight: {delivery.reason}")]
            self.tally.lost += 1
            return [
                self._line(at, "lost", f"{delivery.count} {delivery.topic} message(s): {delivery.reason}")
            ]
        self._disconnected = False
        msg = delivery.msg
        handler = getattr(self, "_on_" + delivery.topic.rsplit("/", 1)[-1], None)
        return handler(at, msg) if handler is not None else []

    def _line(self, at: float, what: str, detail: str) -> str:
        return f"[{at - self._started:7.1f} s] {what:<10} {detail}"

    def _active(self, at: float, what: str, detail: str) -> list[str]:
        self.last_activity = max(self.last_activity, at)
        return [self._line(at, what, detail)]

    def _on_prompt_transcript(self, at: float, msg: dict[str, Any]) -> list[str]:
        self.tally.heard.append(_text(msg.get("data", "")))
        return self._active(at, "heard", f'"{self.tally.heard[-1]}"')

    def _on_response_text(self, at: float, msg: dict[str, Any]) -> list[str]:
        self.tally.replies.append(_text(msg.get("data", "")))
        return self._active(at, "robot", f'"{self.tally.replies[-1]}"')

    def _on_command_status(self, at: float, msg: dict[str, Any]) -> list[str]:
        topic = str(msg.get("topic", ""))
        topic = topic[len(self._prefix) :] if topic.startswith(self._prefix) else topic
        if msg.get("accepted"):
            command = _text(msg.get("command", ""), 80)
            self.tally.routed.append((command, topic))
            return self._active(at, "command", f"{command} -> {topic}: accepted")
        raw, reason = _text(msg.get("raw", ""), 80), _text(msg.get("reason", ""), 200)
        self.tally.refused.append((raw, reason))
        return self._active(at, "command", f'"{raw}" refused: {reason}')

    def _on_attention_state(self, at: float, msg: dict[str, Any]) -> list[str]:
        state = _text(msg.get("data", ""), 40)
        if self.tally.attention and self.tally.attention[-1] == state:
            return []
        self.tally.attention.append(state)
        return self._active(at, "attention", state)

    def _on_agent_metrics(self, at: float, msg: dict[str, Any]) -> list[str]:
        try:
            record = json.loads(str(msg.get("data", "")))
        except json.JSONDecodeError:
            return []
        if not isinstance(record, dict):
            return []
        if record.get("record") == "turn":
            self.tally.turns += 1
            outcome = _text(record.get("outcome", "?"), 40)
            why = _text(record.get("reason", ""), 160)  # a failure's reason: a report, not speech
            detail = (
                f"first audio {_ms(record.get('first_audio_ms'))}, reply done {_ms(record.get('reply_ms'))}"
                f" ({outcome}{': ' + why if why else ''})"
            )
            return self._active(at, "latency", detail)
        if record.get("record") == "session":
            billed = record.get("billed_s")
            billed_text = f"{billed:.1f} s" if isinstance(billed, (int, float)) else "?"
            turns, reason = record.get("turns", "?"), record.get("close_reason", "?")
            detail = f"closed after {billed_text} billed, {turns} turns ({reason})"
            return self._active(at, "session", _text(detail, 200))
        return []

    def _on_playback_status(self, at: float, msg: dict[str, Any]) -> list[str]:
        stream = str(msg.get("stream_id", ""))
        if not stream:
            return []
        if msg.get("finished") or msg.get("interrupted"):
            self._pending_streams.discard(stream)
        else:
            self._pending_streams.add(stream)
        self.last_activity = max(self.last_activity, at)
        return []

    def _on_voice_activity(self, at: float, msg: dict[str, Any]) -> list[str]:
        self._voice_active = bool(msg.get("data"))
        self.last_activity = max(self.last_activity, at)
        return []

    def _on_file_audio_done(self, at: float, msg: dict[str, Any]) -> list[str]:
        if not msg.get("data") or self.file_done:
            return []
        self.file_done = True
        return self._active(at, "file", "the speech file has been played to its end")

    # -- the end ----------------------------------------------------------------------------------

    def settled(self, now: float, grace_s: float) -> bool:
        """The file was played, nobody is speaking, every reply was played, and nothing happened
        for `grace_s` (the agent may still be answering the last utterance until then)."""
        return (
            self.file_done
            and not self._voice_active
            and not self._pending_streams
            and now - self.last_activity >= grace_s
        )

    def pending_replies(self) -> int:
        return len(self._pending_streams)
