"""Node parameters: a node's section of a config file, checked against the node's config dataclass.

Every node declares its ROS parameters from one frozen dataclass, so the graph can check a parameter
before anything starts: ROS silently ignores a parameter a node does not declare, which would turn a
typo (or a config file that drifted from the code) into a setting that never applies.
"""

from __future__ import annotations

import dataclasses
import importlib
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import yaml

from by_your_command.config_files.locate import find_config_file
from by_your_command.graph.model import ParamValue

# executable -> the dataclass its node declares parameters from (imported only when checking).
NODE_CONFIG_TYPES: dict[str, str] = {
    "audio_capture": "by_your_command.audio.devices:CaptureConfig",
    "file_audio_publisher": "by_your_command.audio.file_source:FileSourceConfig",
    "echo_suppressor": "by_your_command.audio.echo:EchoConfig",
    "silero_vad_node": "by_your_command.vad.config:VadConfig",
    "clap_detector_node": "by_your_command.audio.clap:ClapConfig",
    "voice_chunk_recorder": "by_your_command.audio.recording:RecorderConfig",
    "simple_audio_player": "by_your_command.audio.player:PlayerConfig",
    "command_processor": "by_your_command.commands.processor:CommandProcessorConfig",
    "ros_ai_bridge": "by_your_command.bridge.config:BridgeParams",
    "frame_forwarder": "by_your_command.bridge.frames:FrameForwarderParams",
}

Locate = Callable[[str], Path]


class GraphError(ValueError):
    """A graph that cannot be built as asked: the message says what and where."""


def file_section(path: Path, node_name: str) -> dict[str, ParamValue]:
    """The `ros__parameters` a params file gives node `node_name`: `/**` first, then the node's own
    entry (`name`, `/name` or `/**/name`), the way ROS would apply them at the root namespace."""
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as error:
        raise GraphError(f"cannot read params file {path}: {error}") from None
    if not isinstance(data, dict):
        raise GraphError(f"{path}: a params file is a mapping of node names")
    merged: dict[str, ParamValue] = {}
    for key in ("/**", f"{node_name}", f"/{node_name}", f"/**/{node_name}"):
        entry = data.get(key)
        if entry is None:
            continue
        params = entry.get("ros__parameters") if isinstance(entry, dict) else None
        if not isinstance(params, dict):
            raise GraphError(f"{path}: {key} needs a ros__parameters mapping")
        merged.update(params)
    return merged


def config_parameters(file_name: str, node_name: str, locate: Locate = find_config_file) -> dict[str, Any]:
    try:
        path = locate(file_name)
    except FileNotFoundError as error:
        raise GraphError(str(error)) from None
    return file_section(path, node_name)


def _config_type(executable: str) -> Any:
    target = NODE_CONFIG_TYPES.get(executable)
    if target is None:
        raise GraphError(f"unknown executable {executable!r} (known: {', '.join(NODE_CONFIG_TYPES)})")
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


def _coerce(where: str, hint: Any, value: Any) -> Any:
    """The value as the node will declare it (ints become floats where the field is a float)."""
    origin = typing.get_origin(hint)
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise GraphError(f"{where}: must be a list, got {value!r}")
        element = (typing.get_args(hint) or (str,))[0]
        return [_coerce(f"{where}[{index}]", element, item) for index, item in enumerate(value)]
    if hint is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if hint in (bool, int, float, str) and type(value) is hint:
        return value
    raise GraphError(f"{where}: must be {getattr(hint, '__name__', hint)}, got {value!r}")


def check_parameters(
    executable: str, node_name: str, params: Mapping[str, Any], origins: Mapping[str, str] | None = None
) -> dict[str, ParamValue]:
    """`params` with values coerced to the declared types; GraphError for an unknown name, a wrong
    type, or a value the node's own validation refuses. `origins` names where a parameter was set."""
    config_type = _config_type(executable)
    hints = typing.get_type_hints(config_type)
    known = [item.name for item in dataclasses.fields(config_type)]
    checked: dict[str, ParamValue] = {}
    for name, value in params.items():
        if name not in hints or name not in known:
            origin = f" (set in {origins[name]})" if origins and name in origins else ""
            raise GraphError(f"{node_name} has no parameter {name!r}{origin}; it has: {', '.join(known)}")
        checked[name] = _coerce(f"{node_name}.{name}", hints[name], value)
    as_fields = {
        name: tuple(value) if typing.get_origin(hints[name]) is tuple else value
        for name, value in checked.items()
    }
    try:
        config_type(**as_fields)
    except ValueError as error:
        raise GraphError(f"{node_name}: {error}") from None
    return checked
