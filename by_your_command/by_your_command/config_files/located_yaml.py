"""YAML loading that remembers line numbers, so config errors can say where the problem is."""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

# Config files are a few KB; reading (and parsing) a huge one would only stall startup.
MAX_FILE_BYTES = 1 << 20
MAX_FLOW_DEPTH = 64


class LocatedDict(dict[str, Any]):
    """A YAML mapping that knows the line of itself and of each of its keys (1-based)."""

    line: int = 0
    key_lines: dict[str, int]

    def line_of(self, key: str) -> int:
        return self.key_lines.get(key, self.line)


@dataclass(frozen=True)
class ConfigError(Exception):
    """A configuration problem with its file, dotted key path and line (0 when unknown)."""

    file: str
    key: str
    line: int
    message: str

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line else self.file
        return f"{where}: {self.key}: {self.message}" if self.key else f"{where}: {self.message}"


class BoundedSafeLoader(yaml.SafeLoader):
    """yaml.SafeLoader that refuses flow collections (`[`, `{`) nested deeper than MAX_FLOW_DEPTH.

    PyYAML's scanner does work proportional to the flow depth for every token, so "[" * 2000 is
    3 s of CPU before the composer's recursion gives up; real config files nest a few levels.
    """

    def fetch_flow_collection_start(self, TokenClass: Any) -> None:  # noqa: N803 - PyYAML's name
        if self.flow_level >= MAX_FLOW_DEPTH:
            raise yaml.scanner.ScannerError(
                None, None, f"collections nested deeper than {MAX_FLOW_DEPTH} levels", self.get_mark()
            )
        super().fetch_flow_collection_start(TokenClass)


class _LocatingLoader(BoundedSafeLoader):
    pass


def _construct_mapping(loader: _LocatingLoader, node: yaml.MappingNode) -> LocatedDict:
    loader.flatten_mapping(node)
    mapping = LocatedDict()
    mapping.line = node.start_mark.line + 1
    mapping.key_lines = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        line = key_node.start_mark.line + 1
        if not isinstance(key, str):
            raise yaml.constructor.ConstructorError(
                None, None, f"keys must be strings, got {key!r}", key_node.start_mark
            )
        if key in mapping:
            # Plain YAML keeps the last duplicate silently; a duplicated prompt is a real mistake.
            raise yaml.constructor.ConstructorError(
                None,
                None,
                f"duplicate key {key!r} (first on line {mapping.key_lines[key]})",
                key_node.start_mark,
            )
        mapping[key] = loader.construct_object(value_node, deep=True)
        mapping.key_lines[key] = line
    return mapping


_LocatingLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def load_located_yaml(path: Path) -> LocatedDict:
    """Load a YAML file whose top level must be a mapping; errors become ConfigError with a line."""
    try:
        with path.open("rb") as file:
            raw = file.read(MAX_FILE_BYTES + 1)
    except OSError as error:
        raise ConfigError(str(path), "", 0, f"cannot read file: {error.strerror or error}") from error
    if len(raw) > MAX_FILE_BYTES:
        raise ConfigError(str(path), "", 0, f"larger than {MAX_FILE_BYTES} bytes: not a config file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        line = raw[: error.start].count(b"\n") + 1
        raise ConfigError(str(path), "", line, f"not UTF-8 text (byte {error.start})") from None
    try:
        data = yaml.load(text, Loader=_LocatingLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.MarkedYAMLError as error:
        line = error.problem_mark.line + 1 if error.problem_mark is not None else 0
        raise ConfigError(str(path), "", line, f"invalid YAML: {error.problem}") from error
    except yaml.YAMLError as error:
        raise ConfigError(str(path), "", 0, f"invalid YAML: {error}") from error
    except RecursionError:  # PyYAML composes recursively: "[[[[...]]]]" a few hundred deep
        raise ConfigError(str(path), "", 0, "invalid YAML: nested too deeply") from None
    if not isinstance(data, LocatedDict):
        raise ConfigError(str(path), "", 1, "the file must be a YAML mapping at top level")
    return data


class Section:
    """Typed reading of one mapping of a config file, with errors that name file, key and line."""

    def __init__(self, file: str, path: str, data: LocatedDict) -> None:
        self.file = file
        self.path = path
        self.data = data

    def key_path(self, key: str) -> str:
        if not key:
            return self.path
        return f"{self.path}.{key}" if self.path else key

    def error(self, key: str, message: str) -> ConfigError:
        return ConfigError(self.file, self.key_path(key), self.data.line_of(key), message)

    def check_keys(self, allowed: Collection[str], required: Collection[str] = ()) -> None:
        for key in self.data:
            if key not in allowed:
                raise self.error(key, f"unknown key (expected one of: {', '.join(sorted(allowed))})")
        for key in sorted(set(required) - set(self.data)):
            raise ConfigError(self.file, self.key_path(key), self.data.line, "required key is missing")

    def string(self, key: str, default: str | None = None) -> str:
        value = self.data.get(key, default)
        if value is None:
            raise ConfigError(self.file, self.key_path(key), self.data.line, "required key is missing")
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {type(value).__name__}")
        return value

    def section(self, key: str, required: bool = False) -> Section:
        value = self.data.get(key)
        if value is None:
            if required:
                raise ConfigError(
                    self.file, self.key_path(key), self.data.line, "required section is missing"
                )
            empty = LocatedDict()
            empty.line = self.data.line_of(key)
            empty.key_lines = {}
            return Section(self.file, self.key_path(key), empty)
        if not isinstance(value, LocatedDict):
            raise self.error(key, f"must be a mapping, got {type(value).__name__}")
        return Section(self.file, self.key_path(key), value)

    def sections(self) -> list[tuple[str, Section]]:
        """Each key of this mapping whose value must itself be a mapping."""
        return [(key, self.section(key, required=True)) for key in self.data]

    def string_list(self, key: str) -> list[str]:
        value = self.data.get(key, [])
        if not isinstance(value, list) or not all(isinstance(item, str) for item in value):
            raise self.error(key, "must be a list of strings")
        return list(value)
