"""The knobs of a graph: launch arguments and `byc up --set key=value` are the same options.

Everything arrives as text (a launch argument, a command-line word) and is parsed here once, so
both front ends accept exactly the same values. `node.param=value` sets one node parameter.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from by_your_command.graph.params import GraphError

ECHO_MODES = ("gate", "aec", "external")
PROVIDERS = ("openai", "gemini", "gpt_live", "offline")
_NAME_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _option(default: Any, help: str) -> Any:
    return field(default=default, metadata={"help": help})


@dataclass(frozen=True)
class GraphOptions:
    namespace: str = _option("", "the robot's namespace, e.g. grunt1 (every topic moves with it)")
    prefix: str = _option("", "a sub-namespace under namespace, e.g. agent")
    audio_source: str = _option("mic", "mic, or file:<wav path> (no microphone)")
    audio_sink: str = _option("device", "device, or wav:<wav path> (no sound card)")
    echo_mode: str = _option("gate", "gate (half duplex) | aec (barge-in) | external")
    enable_voice_recorder: bool = _option(False, "record utterances (and replies) as WAV files")
    save_mic: bool = _option(False, "also record the raw microphone stream")
    recordings_dir: str = _option(
        "", "where recordings go; empty = $XDG_STATE_HOME/by_your_command/recordings"
    )
    agents: bool = _option(True, "start the profile's agents (false: run them elsewhere)")
    bridge_port: int = _option(9090, "ros_ai_bridge's port; the agents started here connect to it")
    provider: str = _option("offline", "openai | gemini | gpt_live | offline: picks agent_<provider>*.yaml")
    model: str = _option("", "the (conversation) agent's model; empty = its config file's")
    cmd_model: str = _option("", "dual profiles: the command agent's model; empty = its config file's")
    voice: str = _option("", "the speaking agent's voice; empty = its config file's")
    pause_timeout: float = _option(2.0, "seconds of quiet before a cloud session is closed (cost)")
    agent_config_dir: str = _option(
        "", "empty = agent configs are searched like every config file; else taken from this directory only"
    )
    # node name -> parameter -> value, applied over the config files (`--set node.param=value`)
    parameters: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    @property
    def full_namespace(self) -> str:
        parts = [part for text in (self.namespace, self.prefix) for part in text.split("/") if part]
        return "/" + "/".join(parts)

    @property
    def source_file(self) -> str | None:
        return self.audio_source.removeprefix("file:") if self.audio_source.startswith("file:") else None

    @property
    def sink_file(self) -> str | None:
        return self.audio_sink.removeprefix("wav:") if self.audio_sink.startswith("wav:") else None


OPTION_NAMES = tuple(item.name for item in dataclasses.fields(GraphOptions) if item.name != "parameters")
_FIELD_TYPES = {item.name: item.type for item in dataclasses.fields(GraphOptions)}


def parse_bool(text: str) -> bool:
    lowered = text.strip().lower()
    if lowered in ("true", "1", "yes", "on"):
        return True
    if lowered in ("false", "0", "no", "off", ""):
        return False
    raise ValueError(f"not a boolean: {text!r} (true/false)")


def _parse_value(name: str, text: str) -> Any:
    kind = _FIELD_TYPES[name]
    try:
        if kind == "bool":
            return parse_bool(text)
        if kind == "float":
            return float(text)
        if kind == "int":
            return int(text)
    except ValueError as error:
        raise GraphError(f"option {name}: {error}") from None
    return text


def _check_namespace(name: str, value: str) -> None:
    for part in value.split("/"):
        if part and not _NAME_TOKEN.fullmatch(part):
            raise GraphError(f"option {name}: {value!r} is not a ROS namespace (letters, digits, _ and /)")


def _absolute_file(name: str, kind: str, value: str, must_exist: bool) -> str:
    if not value:
        raise GraphError(f"option {name}: {kind}: needs a path, e.g. {kind}:/tmp/speech.wav")
    path = Path(value).expanduser().resolve()
    if must_exist and not path.is_file():
        raise GraphError(f"option {name}: no such file {path}")
    return str(path)


def _checked(options: GraphOptions) -> GraphOptions:
    _check_namespace("namespace", options.namespace)
    _check_namespace("prefix", options.prefix)
    if options.echo_mode not in ECHO_MODES:
        raise GraphError(f"option echo_mode: one of {', '.join(ECHO_MODES)}, got {options.echo_mode!r}")
    if options.provider not in PROVIDERS:
        raise GraphError(f"option provider: one of {', '.join(PROVIDERS)}, got {options.provider!r}")
    if not 0 < options.bridge_port < 65536:
        raise GraphError(f"option bridge_port: 1..65535, got {options.bridge_port}")
    if not options.pause_timeout > 0:
        raise GraphError(f"option pause_timeout: must be > 0 s, got {options.pause_timeout}")
    source, sink = options.audio_source, options.audio_sink
    if options.source_file is not None:
        source = "file:" + _absolute_file("audio_source", "file", options.source_file, must_exist=True)
    elif source != "mic":
        raise GraphError(f"option audio_source: mic or file:<wav path>, got {source!r}")
    if options.sink_file is not None:
        sink = "wav:" + _absolute_file("audio_sink", "wav", options.sink_file, must_exist=False)
    elif sink != "device":
        raise GraphError(f"option audio_sink: device or wav:<wav path>, got {sink!r}")
    return dataclasses.replace(options, audio_source=source, audio_sink=sink)


def parse_options(values: Mapping[str, str], defaults: Mapping[str, str] | None = None) -> GraphOptions:
    """Options from text: `name` -> value for an option, `node.param` -> YAML value for a parameter.
    `defaults` (a profile's) apply first; every value is checked (GraphError says which is wrong)."""
    chosen: dict[str, Any] = {}
    parameters: dict[str, dict[str, Any]] = {}
    for key, text in {**(defaults or {}), **values}.items():
        node, dot, param = key.partition(".")
        if dot:
            if not (node and param):
                raise GraphError(f"--set {key}: a node parameter is written node.param=value")
            try:
                parameters.setdefault(node, {})[param] = yaml.safe_load(text)
            except yaml.YAMLError as error:
                raise GraphError(f"--set {key}: not a YAML value: {error}") from None
        elif key in OPTION_NAMES:
            chosen[key] = _parse_value(key, text)
        else:
            raise GraphError(f"unknown option {key!r} (options: {', '.join(OPTION_NAMES)}; or node.param)")
    return _checked(GraphOptions(**chosen, parameters=parameters))


def parse_assignments(assignments: list[str]) -> dict[str, str]:
    """`key=value` words (from `--set`) as a mapping; the last of a repeated key wins."""
    values: dict[str, str] = {}
    for assignment in assignments:
        key, equals, value = assignment.partition("=")
        if not equals or not key.strip():
            raise GraphError(f"--set {assignment!r}: expected key=value")
        values[key.strip()] = value
    return values
