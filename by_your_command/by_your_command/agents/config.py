"""An agent's configuration: one frozen dataclass with every default, validated at start.

`parse_agent_config` refuses unknown keys, wrong types and impossible values with one message per
problem that names the key; `instructions_for` resolves the prompt (missing prompt id = error). The
API key never lives here: providers read it from the environment, and a key in the file is refused.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any, get_type_hints

import yaml

from by_your_command.prompts.library import PromptLibrary

# Listening noises and fillers: "uh-huh" over the robot's voice means "go on", not "stop".
DEFAULT_BACKCHANNELS = (
    "uh huh", "uh-huh", "mm hm", "mm-hm", "mhm", "hmm", "mm", "yeah", "yep", "okay", "ok", "right",
    "i see", "got it", "sure", "alright", "uh", "um", "oh", "ah", "wow", "cool", "nice",
)  # fmt: skip
MAX_BACKCHANNELS = 200


class AgentRole(str, Enum):
    CONVERSATION = "conversation"  # speaks; the authority of the shared transcript
    COMMAND = "command"  # text out, commands only (dual mode); never audio, never interruptions
    TOOLS = "tools"  # speaks and calls the robot_command tool


class EchoMode(str, Enum):
    GATE = "gate"  # half duplex: the mic is gated while the robot speaks, so no barge-in
    AEC = "aec"  # full duplex: echo cancelled, the user can talk over the robot
    EXTERNAL = "external"  # full duplex with echo control outside this package


class ContextSource(str, Enum):
    OWN = "own"  # the agent's own transcripts (single agent, or the conversation agent)
    SHARED = "shared"  # the conversation agent's published turns (a command agent in dual mode)


@dataclass(frozen=True)
class Topics:
    """Topic names; an empty name disables that input or output."""

    prompt_voice: str = "prompt_voice"
    prompt_text: str = "prompt_text"
    voice_activity: str = "voice_activity"
    playback_status: str = "playback_status"
    attention_state: str = "attention_state"
    camera: str = "camera_forwarded"
    command_status: str = "command_status"
    conversation_reset: str = "conversation_reset"
    safety_stop: str = "safety_stop"  # the VAD heard a stop phrase itself (the stop is already routed)
    robot_tools: str = "robot_tools"  # tools role: the robot's own tools, from the bridge (docs/tools.md)
    response_voice: str = "response_voice"
    response_text: str = "response_text"
    response_cmd: str = "response_cmd"
    command_request: str = "command_request"  # tool calls: verdicts come back with the request's id
    prompt_transcript: str = "prompt_transcript"
    interruption_signal: str = "interruption_signal"
    metrics: str = "agent_metrics"
    detections: str = "detections"  # JSON boxes (docs/gemini.md), when `detections` is on
    # vision_msgs/msg/Detection2DArray, when `detections` is on: off by default, because the bridge
    # can only publish it where vision_msgs is installed (its config/bridge.yaml entry is commented)
    detections_2d: str = ""


@dataclass(frozen=True)
class AgentConfig:
    agent_id: str = "agent"
    role: AgentRole = AgentRole.CONVERSATION
    prompt_id: str = ""  # empty: chosen by the prompt library's selection rules for the role
    prompts_file: str = ""  # empty: the installed prompts.yaml
    echo_mode: EchoMode = EchoMode.GATE
    context_source: ContextSource = ContextSource.OWN
    provider: Mapping[str, Any] = field(default_factory=dict)  # passed to the provider (model, voice…)
    # turn-taking
    utterance_idle_s: float = 2.0  # an utterance with no chunk for this long is closed (lost end marker)
    reply_timeout_s: float = 20.0  # no provider event for this long while a reply is due: turn failed
    # barge-in (full duplex only; docs/agents.md "Interruptions"): the reply pauses at the onset and
    # is cut only when the speech proves real, else it resumes where it paused
    min_barge_in_ms: int = 400  # speech from the VAD's onset (pre-roll, pauses not counted) shorter: noise
    # ...and, heard by the local recogniser, at least this many words that are not backchannels
    # (0: duration alone decides; also when pocketsphinx is missing, with a warning). Two, because
    # the recogniser often hears a lone "uh-huh" as one everyday word; "stop" alone is the safety
    # stop's to hear (docs/vad_and_wake.md)
    min_barge_in_words: int = 2
    # ...or, after this much speech, one such word: the recogniser merges words it does not know into
    # fillers ("turn to the left now" over the robot: "soon oh"), and backchannels are short
    # (bench_barge_in aec: every backchannel and cough <= 608 ms, real misses >= 960 ms). 0: off
    long_barge_in_ms: int = 900
    backchannels: tuple[str, ...] = DEFAULT_BACKCHANNELS  # said over the robot, they never interrupt
    barge_in_window_s: float = 1.5  # onset without that much proof within this window: resume
    # session cycling
    pause_timeout_s: float = 2.0  # bench_billing: each exchange bills about this much extra
    max_session_s: float = 3600.0  # also capped by the provider's own limit
    rotation_margin_s: float = 120.0  # rotate this long before the limit, at a turn boundary
    connect_timeout_s: float = 10.0
    connect_attempts: int = 4  # per pending turn, before its input is reported undeliverable
    backoff_initial_s: float = 0.5
    backoff_max_s: float = 10.0
    op_timeout_s: float = 5.0  # one send to the provider
    close_timeout_s: float = 3.0
    publish_timeout_s: float = 2.0  # one publish to the robot
    connect_buffer_s: float = 30.0  # user audio held while a session connects
    # context
    max_context_tokens: int = 2000
    max_context_age_s: float = 1800.0
    conversation_timeout_s: float = 600.0  # inactivity that starts a new conversation
    # tools, camera
    tool_verdict_timeout_s: float = 3.0
    # A robot action's session stays open until the action ends, so the result goes to the call
    # that asked for it (docs/tools.md). Sessions are billed while open: false closes it at the
    # pause as usual, and the result is told to the next session as a note.
    keep_session_while_acting: bool = True
    max_frame_age_s: float = 5.0
    # A frame that arrived this long before a question's first audio is of its time; an older one
    # goes only if none arrives while the question is spoken.
    frame_lead_s: float = 0.5
    # object detections (Gemini's box_2d JSON) in the model's text are published on topics.detections
    # (never on response_cmd, whatever this says); off: they are counted and dropped
    detections: bool = False
    topics: Topics = field(default_factory=Topics)

    @property
    def speaks(self) -> bool:
        return self.role is not AgentRole.COMMAND

    @property
    def barge_in(self) -> bool:
        return self.speaks and self.echo_mode is not EchoMode.GATE


class AgentConfigError(ValueError):
    def __init__(self, problems: list[str], source: str = "agent config") -> None:
        super().__init__(f"{source}: " + "; ".join(problems))
        self.problems = problems


_SECRET_KEYS = frozenset({"api_key", "openai_api_key", "key", "token", "secret"})
_POSITIVE = {
    "utterance_idle_s", "reply_timeout_s", "barge_in_window_s", "pause_timeout_s", "max_session_s",
    "connect_timeout_s", "connect_attempts", "backoff_initial_s", "backoff_max_s", "op_timeout_s",
    "close_timeout_s", "publish_timeout_s", "connect_buffer_s", "max_context_tokens", "max_context_age_s",
    "conversation_timeout_s", "tool_verdict_timeout_s", "max_frame_age_s",
}  # fmt: skip


def _convert(path: str, hint: Any, value: Any, problems: list[str]) -> Any:
    if isinstance(hint, type) and issubclass(hint, Enum):
        allowed = [member.value for member in hint]
        if value not in allowed:
            problems.append(f"{path}: must be one of {allowed}, got {value!r}")
        return hint(value) if value in allowed else None
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        return _build(hint, value, path, problems)
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
            problems.append(f"{path}: must be a number, got {value!r}")
            return None
        return float(value)
    if hint == tuple[str, ...]:
        if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
            problems.append(f"{path}: must be a list of strings, got {value!r}")
            return None
        return tuple(value)
    if hint is int or hint is str or hint is bool:
        if type(value) is not hint:
            problems.append(f"{path}: must be {hint.__name__}, got {type(value).__name__} {value!r}")
            return None
        return value
    # Mapping[str, Any]: the provider validates its own section
    if not isinstance(value, Mapping) or not all(isinstance(key, str) for key in value):
        problems.append(f"{path}: must be a mapping with string keys")
        return None
    secrets = sorted(key for key in value if key.lower() in _SECRET_KEYS)
    if secrets:
        problems.append(f"{path}.{secrets[0]}: keys come from the environment (OPENAI_API_KEY), not files")
    return dict(value)


def _build(cls: Any, data: Any, prefix: str, problems: list[str]) -> Any:
    if not isinstance(data, Mapping):
        problems.append(f"{prefix or 'config'}: must be a mapping, got {type(data).__name__}")
        return None
    hints = get_type_hints(cls)
    names = {item.name for item in dataclasses.fields(cls)}
    for key in data:
        if key not in names:
            where = f"{prefix}.{key}" if prefix else str(key)
            if str(key).lower() in _SECRET_KEYS:
                problems.append(f"{where}: keys come from the environment (OPENAI_API_KEY), not files")
            else:
                problems.append(f"{where}: unknown key (known: {', '.join(sorted(names))})")
    values = {}
    for name in names & set(data):
        path = f"{prefix}.{name}" if prefix else name
        converted = _convert(path, hints[name], data[name], problems)
        if converted is None:
            continue
        if name in _POSITIVE and converted <= 0:
            problems.append(f"{path}: must be > 0, got {converted!r}")
        values[name] = converted
    if problems:
        return None
    return cls(**values)


def parse_agent_config(data: Any, source: str = "agent config") -> AgentConfig:
    problems: list[str] = []
    config = _build(AgentConfig, {} if data is None else data, "", problems)
    if config is not None:
        if config.min_barge_in_ms < 0:
            problems.append(f"min_barge_in_ms: must be >= 0, got {config.min_barge_in_ms}")
        if config.long_barge_in_ms != 0 and config.long_barge_in_ms < config.min_barge_in_ms:
            problems.append(
                f"long_barge_in_ms: 0 (off) or >= min_barge_in_ms ({config.min_barge_in_ms}), "
                f"got {config.long_barge_in_ms}"
            )
        if not 0 <= config.min_barge_in_words <= 20:
            problems.append(f"min_barge_in_words: must be within 0..20, got {config.min_barge_in_words}")
        if len(config.backchannels) > MAX_BACKCHANNELS or any(
            not phrase.strip() or len(phrase) > 40 for phrase in config.backchannels
        ):
            problems.append(f"backchannels: at most {MAX_BACKCHANNELS} phrases of 1..40 characters")
        if not 0 <= config.frame_lead_s <= config.max_frame_age_s:
            problems.append(f"frame_lead_s: must be within 0..max_frame_age_s, got {config.frame_lead_s}")
        if config.backoff_initial_s > config.backoff_max_s:
            problems.append("backoff_initial_s: must not exceed backoff_max_s")
        if not config.agent_id.strip():
            problems.append("agent_id: must not be empty")
    if problems:
        raise AgentConfigError(problems, source)
    assert isinstance(config, AgentConfig)
    return config


def load_agent_config(path: str | Path) -> AgentConfig:
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as error:
        raise AgentConfigError([f"cannot read: {error}"], str(path)) from None
    return parse_agent_config(data, str(path))


def instructions_for(config: AgentConfig, library: PromptLibrary) -> str:
    """The expanded system prompt: `prompt_id`, or the library's choice for the agent's role.
    Raises AgentConfigError for a prompt id the library does not have."""
    prompt_id = config.prompt_id or library.select_prompt({"agent_role": config.role.value})
    if prompt_id not in library.prompts:
        raise AgentConfigError(
            [f"prompt_id: no prompt {prompt_id!r} in {library.source} (have: {', '.join(library.prompts)})"]
        )
    return library.system_prompt(prompt_id)
