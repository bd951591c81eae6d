"""What a graph is made of: ROS nodes and agent processes, fully resolved (no ROS imported).

A `Graph` is the one description that launch files and `byc up` both start, so they cannot drift:
every value here is concrete (parameters already merged from config files and overrides).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

PACKAGE = "by_your_command"

# A ROS parameter value as YAML writes it: bool, int, float, str, or a list of one of them.
ParamValue = Any


@dataclass(frozen=True)
class NodeSpec:
    """One ROS node: an executable of PACKAGE started under `name` in the graph's namespace."""

    name: str  # node name, unique in the graph; also the log prefix of `byc up`
    executable: str
    parameters: Mapping[str, ParamValue] = field(default_factory=dict)
    remappings: tuple[tuple[str, str], ...] = ()
    param_sources: tuple[str, ...] = ()  # config files the parameters started from (for people)


@dataclass(frozen=True)
class AgentSpec:
    """One agent process (not a ROS node: it talks to ros_ai_bridge over a WebSocket).

    Started as `<executable> <*arguments> --config <file>`, where the file is `config_file` with
    `overrides` merged in (written next to the run, so the original is never edited)."""

    name: str
    config_file: str  # file name searched in the config directories, or a path
    overrides: Mapping[str, Any] = field(default_factory=dict)  # nested mappings merge
    executable: str = "byc"
    arguments: tuple[str, ...] = ("agent",)


@dataclass(frozen=True)
class Graph:
    profile: str
    namespace: str  # absolute ("/" = root); every topic is relative, so this moves the whole graph
    nodes: tuple[NodeSpec, ...]
    agents: tuple[AgentSpec, ...] = ()

    def node(self, name: str) -> NodeSpec:
        for node in self.nodes:
            if node.name == name:
                return node
        raise KeyError(f"no node {name!r} in profile {self.profile!r} (nodes: {self.node_names()})")

    def node_names(self) -> str:
        return ", ".join(node.name for node in self.nodes)
