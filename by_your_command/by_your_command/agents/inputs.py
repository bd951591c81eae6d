"""What the robot tells an agent, typed. The port that produces these has already validated them;
the runtime still treats every value as untrusted (rates, ids and lengths are checked again)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Any

from by_your_command.agents.provider import Role


class Attention(str, Enum):
    AWAKE = "awake"
    ASLEEP = "asleep"
    MUTED = "muted"


@dataclass(frozen=True)
class UtteranceChunk:
    """A piece of one utterance cut by our VAD (`prompt_voice`); exactly one chunk has `is_end`."""

    pcm: bytes  # mono int16 LE
    sample_rate: int
    utterance_id: int
    chunk_sequence: int
    is_end: bool
    # Of the utterance up to the end of this chunk, samples the VAD did not judge speech (pre-roll,
    # pauses); 0 from a VAD that does not say. Speech heard = samples received - this.
    unvoiced_samples: int = 0


@dataclass(frozen=True)
class PromptText:
    """A typed user turn (`prompt_text`)."""

    text: str


@dataclass(frozen=True)
class VoiceActivity:
    """Our VAD's speech flag (`voice_activity`): True is a speech onset."""

    active: bool


@dataclass(frozen=True)
class PlaybackStatus:
    """What the player really played of one reply (`playback_status`)."""

    stream_id: str
    played_ms: int
    queued_ms: int = 0
    speaking: bool = False
    finished: bool = False
    interrupted: bool = False
    starved: bool = False
    paused: bool = False  # held by our pause (a barge-in being judged)


@dataclass(frozen=True)
class AttentionChanged:
    state: Attention


@dataclass(frozen=True)
class CameraFrame:
    jpeg: bytes
    stamp: float = 0.0  # the image's header stamp, seconds (detections carry it)
    frame_id: str = ""


@dataclass(frozen=True)
class CommandStatus:
    """The command processor's verdict on one command (`command_status`)."""

    raw: str
    command: str
    accepted: bool
    reason: str
    topic: str = ""
    request_id: str = ""  # the CommandRequest it answers ("" for a response_cmd message)
    index: int = 0  # its place among that message's verdicts
    count: int = 1  # how many verdicts that message produced


@dataclass(frozen=True)
class InputLost:
    """Messages of `topic` that will never arrive (`count` None: unknown how many)."""

    topic: str
    count: int | None
    reason: str


@dataclass(frozen=True)
class ConversationReset:
    """Start a new conversation (external reset); empty id: the agent makes one."""

    conversation_id: str = ""


@dataclass(frozen=True)
class SafetyStop:
    """The robot heard a stop phrase itself (`safety_stop`): the stop command is already routed and
    every reply cut; the agent drops what it was saying and tells the model. `utterance_id` names
    the utterance that held the stop word (0: none): it is not a request to the model."""

    phrase: str
    utterance_id: int = 0


@dataclass(frozen=True)
class SharedTurn:
    """A turn of the shared transcript published by the conversation agent (dual mode)."""

    role: Role
    text: str


@dataclass(frozen=True)
class ToolCatalog:
    """The robot's tools (`robot_tools`, JSON from the bridge, docs/tools.md); untrusted until parsed."""

    text: str


@dataclass(frozen=True)
class CallReplied:
    """A service's response or an action goal's end, for the request id we sent (docs/tools.md)."""

    request_id: str
    ok: bool
    values: Any  # the response/result fields when ok
    error: str = ""
    code: str = ""  # the bridge's reason on failure (no_server, rejected, timeout, ...)
    status: int = 0  # actions: action_msgs/GoalStatus
    is_action: bool = False


@dataclass(frozen=True)
class CallFeedback:
    """An action goal's feedback, for the request id we sent."""

    request_id: str
    values: dict[str, Any]


RobotInput = (
    UtteranceChunk
    | PromptText
    | VoiceActivity
    | PlaybackStatus
    | AttentionChanged
    | CameraFrame
    | CommandStatus
    | InputLost
    | ConversationReset
    | SharedTurn
    | SafetyStop
    | ToolCatalog
    | CallReplied
    | CallFeedback
)
