"""The profiles: which nodes and agents make each graph, and with which parameters.

Names follow the earlier project's launch files (byc, oai_realtime, oai_dual_agent, gemini_live,
gemini_dual_agent) plus offline and gpt_live. Node parameters start from the config files in
config/ (the node's section), then what the profile and options set, then `node.param` overrides:
later wins.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from by_your_command.agents.app_config import FULL_DUPLEX
from by_your_command.config_files.locate import find_config_file
from by_your_command.graph.model import AgentSpec, Graph, NodeSpec
from by_your_command.graph.options import GraphOptions
from by_your_command.graph.params import GraphError, Locate, check_parameters, config_parameters

FILE_LEAD_SILENCE_MS = 1000  # a file source starts with this much silence: the VAD settles on it


class Agents(Enum):
    NONE = "none"  # voice detection only: utterances on prompt_voice for whoever listens
    SINGLE = "single"  # one agent that talks (and commands through the command processor)
    DUAL = "dual"  # a conversation agent and a command agent


@dataclass(frozen=True)
class Profile:
    name: str
    description: str
    agents: Agents
    vision: bool = False  # frame_forwarder sends camera frames to the agents
    defaults: Mapping[str, str] = field(default_factory=dict)  # option defaults, as text


PROFILES: dict[str, Profile] = {
    profile.name: profile
    for profile in (
        Profile(
            "byc",
            "voice detection only: microphone, echo control, VAD (and the utterance recorder)",
            Agents.NONE,
            defaults={"enable_voice_recorder": "true"},
        ),
        Profile(
            "oai_realtime",
            "one OpenAI Realtime agent that talks and sends commands",
            Agents.SINGLE,
            defaults={"provider": "openai", "pause_timeout": "2.0"},
        ),
        Profile(
            "oai_dual_agent",
            "OpenAI Realtime: a conversation agent and a command agent",
            Agents.DUAL,
            defaults={"provider": "openai", "pause_timeout": "2.0"},
        ),
        Profile(
            "gemini_live",
            "one Gemini Live agent with camera frames",
            Agents.SINGLE,
            vision=True,
            defaults={"provider": "gemini", "pause_timeout": "2.0"},
        ),
        Profile(
            "gemini_dual_agent",
            "Gemini Live with camera frames: a conversation agent and a command agent",
            Agents.DUAL,
            vision=True,
            defaults={"provider": "gemini", "pause_timeout": "2.0"},
        ),
        Profile(
            "gpt_live",
            "one OpenAI GPT-Live agent (full duplex: echo-cancelled microphone) that talks and acts",
            Agents.SINGLE,
            # GPT-Live hears the microphone while it speaks and decides itself when the user talks
            # over it: it needs the robot's own voice cancelled (aec), never a gated mic.
            defaults={"provider": "gpt_live", "echo_mode": "aec", "pause_timeout": "2.0"},
        ),
        Profile(
            "offline",
            "the offline agent: no network, no API key",
            Agents.SINGLE,
            defaults={"provider": "offline", "pause_timeout": "10.0"},
        ),
    )
}

# Providers with one agent config (it talks and acts), no conversation / command pair.
SINGLE_AGENT_PROVIDERS = {"offline": "agent_offline.yaml", "gpt_live": "agent_gpt_live.yaml"}

# Options that only mean something where agents run.
AGENT_OPTIONS = frozenset(
    {"audio_sink", "agents", "bridge_port", "provider", "model", "voice", "pause_timeout", "agent_config_dir"}
)


@dataclass(frozen=True)
class LaunchArgument:
    name: str
    default: str  # launch arguments are text
    description: str


def profile(name: str) -> Profile:
    try:
        return PROFILES[name]
    except KeyError:
        raise GraphError(f"unknown profile {name!r} (profiles: {', '.join(PROFILES)})") from None


def _as_text(value: Any) -> str:
    return str(value).lower() if isinstance(value, bool) else str(value)


def launch_arguments(name: str) -> tuple[LaunchArgument, ...]:
    """The options a profile takes, with its defaults: the arguments of its launch file."""
    chosen = profile(name)
    arguments = []
    for item in dataclasses.fields(GraphOptions):
        if item.name == "parameters":
            continue
        if chosen.agents is Agents.NONE and item.name in AGENT_OPTIONS:
            continue
        if chosen.agents is not Agents.DUAL and item.name == "cmd_model":
            continue
        default = chosen.defaults.get(item.name, _as_text(item.default))
        arguments.append(LaunchArgument(item.name, default, item.metadata["help"]))
    return tuple(arguments)


@dataclass(frozen=True)
class _Draft:
    """A node before its config file section, overrides and checks are applied."""

    name: str
    executable: str
    param_file: str | None = None  # config file whose section for `executable` starts the parameters
    parameters: Mapping[str, Any] = field(default_factory=dict)
    remappings: tuple[tuple[str, str], ...] = ()


def _recordings(options: GraphOptions, kind: str) -> str:
    return f"{options.recordings_dir.rstrip('/')}/{kind}" if options.recordings_dir else ""


def _drafts(chosen: Profile, options: GraphOptions) -> list[_Draft]:
    with_agents = chosen.agents is not Agents.NONE
    drafts: list[_Draft] = []
    vad: dict[str, Any] = {}
    if options.echo_mode == "aec":
        drafts.append(_Draft("echo_suppressor", "echo_suppressor", "audio_io.yaml", {"mode": "aec"}))
    else:
        # gate and external need no echo_suppressor: the VAD reads `audio` and gates on
        # assistant_speaking itself (one process and one message per block less: ~1.5 % of a core).
        vad = {"input_topic": "audio", "echo_gate": options.echo_mode == "gate"}
    drafts.append(_Draft("silero_vad_node", "silero_vad_node", "vad.yaml", vad))
    if with_agents:
        drafts.append(_Draft("clap_detector_node", "clap_detector_node", "vad.yaml"))
    if options.enable_voice_recorder:
        utterances = {"input_mode": "utterance", "output_dir": _recordings(options, "utterances")}
        drafts.append(_Draft("voice_recorder", "voice_chunk_recorder", None, utterances))
        if with_agents:
            replies = {"input_mode": "stream", "output_dir": _recordings(options, "replies")}
            drafts.append(_Draft("reply_recorder", "voice_chunk_recorder", None, replies))
    if options.save_mic:
        mic = {"input_mode": "stream", "output_dir": _recordings(options, "mic")}
        drafts.append(
            _Draft("mic_recorder", "voice_chunk_recorder", None, mic, (("response_voice", "audio"),))
        )
    if with_agents:
        sink = {"sink": "wav", "wav_path": options.sink_file} if options.sink_file else {"sink": "device"}
        drafts += [
            _Draft("simple_audio_player", "simple_audio_player", "audio_io.yaml", sink),
            _Draft("ros_ai_bridge", "ros_ai_bridge", None, {"port": options.bridge_port}),
            _Draft("command_processor", "command_processor"),
        ]
    if chosen.vision:
        drafts.append(_Draft("frame_forwarder", "frame_forwarder"))
    # What listens to `audio`: a file source waits for all of it before playing. Not the clap
    # detector: it listens only while the robot is not awake.
    listeners = sum(
        1
        for d in drafts
        if d.name in ("echo_suppressor", "mic_recorder") or d.parameters.get("input_topic") == "audio"
    )
    if options.source_file:
        source = {
            "files": [options.source_file],
            "min_subscribers": listeners,
            "lead_silence_ms": FILE_LEAD_SILENCE_MS,
        }
        if chosen.agents is not Agents.NONE and options.agents:
            # Speech must not start before an agent listens: the bridge subscribes to prompt_voice
            # only once a client does, and an utterance cut at its start is misheard.
            source["wait_for_topic"] = "prompt_voice"
        drafts.insert(0, _Draft("file_audio_publisher", "file_audio_publisher", None, source))
    else:
        drafts.insert(0, _Draft("audio_capture", "audio_capture", "audio_io.yaml"))
    return drafts


def _agents(chosen: Profile, options: GraphOptions) -> tuple[AgentSpec, ...]:
    if chosen.agents is Agents.NONE or not options.agents:
        return ()

    def config(name: str) -> str:
        return f"{options.agent_config_dir.rstrip('/')}/{name}" if options.agent_config_dir else name

    def overrides(model: str, voice: str) -> dict[str, Any]:
        provider = {key: value for key, value in (("model", model), ("voice", voice)) if value}
        base: dict[str, Any] = {
            "echo_mode": options.echo_mode,
            "pause_timeout_s": options.pause_timeout,
            "bridge": {"url": f"ws://127.0.0.1:{options.bridge_port}"},  # this graph's bridge
        }
        return {**base, "provider": provider} if provider else base

    if chosen.agents is Agents.SINGLE:
        # One agent that talks and sends commands: the cloud providers' tool mode (robot_command).
        single = SINGLE_AGENT_PROVIDERS.get(options.provider, f"agent_{options.provider}_tool.yaml")
        return (AgentSpec("agent", config(single), overrides(options.model, options.voice)),)
    if options.provider in SINGLE_AGENT_PROVIDERS:
        raise GraphError(
            f"option provider: {options.provider} has one agent that talks and acts, no conversation "
            f"and command pair: use profile {options.provider}"
        )
    return (
        AgentSpec(
            "conversation_agent",
            config(f"agent_{options.provider}.yaml"),
            overrides(options.model, options.voice),
        ),
        AgentSpec(
            "command_agent",
            config(f"agent_{options.provider}_command.yaml"),
            overrides(options.cmd_model, ""),
        ),
    )


def _check_echo_mode(chosen: Profile, options: GraphOptions) -> None:
    """A full-duplex agent with a gated microphone would never hear the user over the robot, and
    the agent refuses it: say so before anything starts."""
    if chosen.agents is Agents.NONE or not options.agents:
        return
    if options.provider in FULL_DUPLEX and options.echo_mode == "gate":
        raise GraphError(
            f"option echo_mode: provider {options.provider} is full duplex and needs the echo-cancelled "
            "microphone: echo_mode aec (or external, where the hardware cancels the echo), not gate"
        )


def build_graph(name: str, options: GraphOptions, locate: Locate = find_config_file) -> Graph:
    """The graph of profile `name` with `options`; GraphError when a value or a file is wrong."""
    chosen = profile(name)
    _check_echo_mode(chosen, options)
    drafts = _drafts(chosen, options)
    names = [draft.name for draft in drafts]
    unknown = sorted(set(options.parameters) - set(names))
    if unknown:
        raise GraphError(f"no node {unknown[0]!r} in profile {name!r} (nodes: {', '.join(names)})")
    nodes = []
    for draft in drafts:
        from_file = config_parameters(draft.param_file, draft.executable, locate) if draft.param_file else {}
        overrides = options.parameters.get(draft.name, {})
        parameters = {**from_file, **draft.parameters, **overrides}
        origins = {
            **{key: f"config/{draft.param_file}" for key in from_file},
            **{key: f"--set {draft.name}.{key}" for key in overrides},
        }
        nodes.append(
            NodeSpec(
                name=draft.name,
                executable=draft.executable,
                parameters=check_parameters(draft.executable, draft.name, parameters, origins),
                remappings=draft.remappings,
                param_sources=(draft.param_file,) if draft.param_file else (),
            )
        )
    return Graph(chosen.name, options.full_namespace, tuple(nodes), _agents(chosen, options))
