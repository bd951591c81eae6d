"""The robot's tools as the model sees them: built by the bridge from tools.yaml and the installed
interfaces, published as JSON on `robot_tools`, read back (untrusted) by the agents.

A RobotTool knows its schema, how the model's arguments become the request / goal / message (or a
command's text), how to summarise its feedback and the phrases the offline agent hears.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from by_your_command.tools.arguments import build_message, check_schema, parse_arguments, validate
from by_your_command.tools.checks import MAX_TOOL_ARGUMENTS, argument_paths, check_tool
from by_your_command.tools.config import (
    CONFIRMED,
    KINDS,
    MAX_TOOLS,
    ArgumentConfig,
    FeedbackRule,
    ToolConfig,
    ToolKind,
    ToolRules,
    ToolsConfig,
    template_names,
)
from by_your_command.tools.errors import CatalogError, ToolArgumentError, ToolsConfigError
from by_your_command.tools.interface_types import INPUT_PART, Field, Interface, InterfaceError, Message
from by_your_command.tools.schema import (
    SchemaProblem,
    argument_schema,
    choices_schema,
    field_schema,
    message_schema,
    parameters_schema,
)
from by_your_command.tools.values import leaf_paths, overlap

__all__ = [
    "Catalog",
    "CatalogError",
    "RobotTool",
    "ToolArgument",
    "ToolArgumentError",
    "ToolsConfigError",
    "build_catalog",
]

CATALOG_VERSION = 1
MAX_CATALOG_CHARS = 2_000_000  # it travels as one bridge message
MAX_SUMMARY_CHARS = 300
_TOOL_KEYS = {
    "name",
    "description",
    "kind",
    "ros_name",
    "type",
    "parameters",
    "fixed",
    "arguments",
    "command",
    "rules",
    "feedback",
    "spoken",
}


@dataclass(frozen=True)
class ToolArgument:
    """How one model argument becomes message fields."""

    name: str
    field: str = ""  # dotted path its value goes to ("" = a choice's fields at the top)
    choices: dict[str, Any] | None = None  # name → value (None: the model's own value)


@dataclass(frozen=True)
class RobotTool:
    name: str
    description: str
    kind: ToolKind
    ros_name: str  # "" for command tools
    type: str  # pkg/action/T, pkg/srv/T, pkg/msg/T; "" for command tools
    parameters: dict[str, Any]  # the JSON Schema object the model sees
    fixed: dict[str, Any] = field(default_factory=dict)
    arguments: tuple[ToolArgument, ...] = ()
    command: str = ""  # command tools: "pan@{direction}"
    rules: ToolRules = ToolRules()
    feedback: FeedbackRule | None = None  # actions: which feedback fields are told, how often
    spoken: tuple[str, ...] = ()  # offline phrases, "{arg}" = each of its choices

    def values(self, arguments_json: str) -> dict[str, Any]:
        """The model's arguments, parsed and checked (ToolArgumentError says what is wrong)."""
        values: dict[str, Any] = validate(self.parameters, parse_arguments(arguments_json))
        if self.rules.confirm and values.get(CONFIRMED) is not True:
            raise ToolArgumentError("'confirmed' must be true, and only after the user said yes")
        return values

    def build(self, arguments_json: str) -> dict[str, Any]:
        """The request / goal / message dict: fixed fields + the chosen values + the model's."""
        if self.kind == "command":
            raise ValueError(f"{self.name} is a command tool: use command_text")
        values = self.values(arguments_json)
        contributions = []
        for argument in self.arguments:
            if argument.name not in values:
                continue
            value = values[argument.name]
            contributions.append(
                (argument.field, argument.choices[value] if argument.choices is not None else value)
            )
        return build_message(self.fixed, contributions)

    def command_text(self, arguments_json: str) -> str:
        """A command tool's template filled with the chosen values (`pan@left`)."""
        if self.kind != "command":
            raise ValueError(f"{self.name} is a {self.kind} tool: use build")
        values = self.values(arguments_json)
        text = self.command
        for argument in self.arguments:
            if argument.choices is not None:
                text = text.replace(f"{{{argument.name}}}", str(argument.choices[values[argument.name]]))
        return text

    def feedback_summary(self, values: dict[str, Any]) -> str:
        """`distance_remaining 3.2, estimated_time_remaining 41 s`: the chosen feedback fields,
        numbers rounded; "" when the tool tells no feedback."""
        if self.feedback is None or not isinstance(values, dict):
            return ""
        parts = []
        for path in self.feedback.fields:
            value: Any = values
            for name in path.split("."):
                value = value.get(name) if isinstance(value, dict) else None
            if value is not None:
                parts.append(f"{path} {_brief(value)}")
        text = ", ".join(parts)
        return text if len(text) <= MAX_SUMMARY_CHARS else text[: MAX_SUMMARY_CHARS - 1] + "…"

    def spoken_forms(self) -> list[tuple[str, dict[str, str]]]:
        """(phrase, arguments) for every spoken template and every choice of its arguments."""
        choices = {a.name: list(a.choices) for a in self.arguments if a.choices is not None}
        forms: list[tuple[str, dict[str, str]]] = []
        for template in self.spoken:
            names = sorted(template_names(template))
            for picked in itertools.product(*(choices[name] for name in names)):
                arguments = dict(zip(names, picked, strict=True))
                phrase = template
                for name, choice in arguments.items():
                    phrase = phrase.replace(f"{{{name}}}", choice)
                forms.append((phrase, arguments))
        return forms

    def to_dict(self) -> dict[str, Any]:
        arguments = []
        for argument in self.arguments:
            entry: dict[str, Any] = {"name": argument.name, "field": argument.field}
            if argument.choices is not None:
                entry["choices"] = argument.choices
            arguments.append(entry)
        rules = self.rules
        return {
            "name": self.name,
            "description": self.description,
            "kind": self.kind,
            "ros_name": self.ros_name,
            "type": self.type,
            "parameters": self.parameters,
            "fixed": self.fixed,
            "arguments": arguments,
            "command": self.command,
            "rules": {
                "while_asleep": rules.while_asleep,
                "min_interval_s": rules.min_interval_s,
                "max_duration_s": rules.max_duration_s,
                "confirm": rules.confirm,
                "timeout_s": rules.timeout_s,
            },
            "feedback": None
            if self.feedback is None
            else {"every_s": self.feedback.every_s, "fields": list(self.feedback.fields)},
            "spoken": list(self.spoken),
        }


def _brief(value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return _rounded(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, dict) and set(value) == {"sec", "nanosec"}:  # a Time or Duration
        sec, nanosec = value["sec"], value["nanosec"]
        if isinstance(sec, int) and isinstance(nanosec, int):
            return f"{_rounded(sec + nanosec / 1e9)} s"
    text = value if isinstance(value, str) else json.dumps(value, separators=(",", ":"), default=str)
    return text if len(text) <= 80 else text[:79] + "…"


def _rounded(value: float) -> str:
    if not math.isfinite(value):
        return str(value)
    text = f"{value:.2f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text


@dataclass(frozen=True)
class Catalog:
    tools: tuple[RobotTool, ...] = ()

    def get(self, name: str) -> RobotTool | None:
        return next((tool for tool in self.tools if tool.name == name), None)

    def to_json(self) -> str:
        data = {"version": CATALOG_VERSION, "tools": [tool.to_dict() for tool in self.tools]}
        return json.dumps(data, ensure_ascii=False, separators=(",", ":"), allow_nan=False)

    @classmethod
    def from_json(cls, text: str) -> Catalog:
        """A catalog received over the bridge (untrusted): anything odd is a CatalogError."""
        if not isinstance(text, (str, bytes)) or len(text) > MAX_CATALOG_CHARS:
            raise CatalogError(f"the catalog must be JSON text of at most {MAX_CATALOG_CHARS} characters")
        try:
            data = json.loads(text, parse_constant=_refuse_constant, object_pairs_hook=_unique_keys)
        except RecursionError:
            raise CatalogError("the catalog is nested too deeply") from None
        except ValueError as error:
            raise CatalogError(f"the catalog is not valid JSON: {error}") from None
        if not isinstance(data, dict) or set(data) != {"version", "tools"}:
            raise CatalogError("the catalog must be an object with 'version' and 'tools'")
        if data["version"] != CATALOG_VERSION or isinstance(data["version"], bool):
            raise CatalogError(
                f"unknown catalog version {data['version']!r} (this agent reads {CATALOG_VERSION})"
            )
        tools = data["tools"]
        if not isinstance(tools, list):
            raise CatalogError("'tools' must be a list")
        parsed = tuple(_tool_from_dict(entry, index) for index, entry in enumerate(tools))
        try:
            check_catalog(parsed)
        except ValueError as error:
            raise CatalogError(str(error)) from None
        return cls(parsed)


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not allowed")


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {key!r}")
        out[key] = value
    return out


def check_catalog(tools: tuple[RobotTool, ...]) -> None:
    """Every tool consistent, names unique (also ignoring case), not too many."""
    if len(tools) > MAX_TOOLS:
        raise ValueError(f"{len(tools)} tools, at most {MAX_TOOLS} are allowed")
    seen: set[str] = set()
    for tool in tools:
        check_tool(tool)
        if tool.name.lower() in seen:
            raise ValueError(f"tool {tool.name!r} is listed twice")
        seen.add(tool.name.lower())


def _tool_from_dict(entry: Any, index: int) -> RobotTool:
    where = f"tools[{index}]"
    if not isinstance(entry, dict) or set(entry) != _TOOL_KEYS:
        raise CatalogError(f"{where}: expected an object with exactly {sorted(_TOOL_KEYS)}")
    name = entry["name"]
    where = f"tool {name!r}" if isinstance(name, str) and len(name) <= 64 else where
    try:
        for key in ("name", "description", "kind", "ros_name", "type", "command"):
            if not isinstance(entry[key], str):
                raise ValueError(f"{key} must be text")
        if entry["kind"] not in KINDS:
            raise ValueError(f"unknown kind {entry['kind'][:40]!r}")
        for key in ("parameters", "fixed"):
            if not isinstance(entry[key], dict):
                raise ValueError(f"{key} must be an object")
        check_schema(entry["parameters"])
        if not isinstance(entry["spoken"], list) or not all(isinstance(s, str) for s in entry["spoken"]):
            raise ValueError("spoken must be a list of texts")
        return RobotTool(
            name=name,
            description=entry["description"],
            kind=entry["kind"],
            ros_name=entry["ros_name"],
            type=entry["type"],
            parameters=entry["parameters"],
            fixed=entry["fixed"],
            arguments=_arguments_from(entry["arguments"]),
            command=entry["command"],
            rules=_rules_from(entry["rules"]),
            feedback=_feedback_from(entry["feedback"]),
            spoken=tuple(entry["spoken"]),
        )
    except ValueError as error:
        raise CatalogError(f"{where}: {error}") from None


def _arguments_from(raw: Any) -> tuple[ToolArgument, ...]:
    if not isinstance(raw, list) or len(raw) > MAX_TOOL_ARGUMENTS:
        raise ValueError("arguments must be a short list")
    arguments = []
    for entry in raw:
        if not isinstance(entry, dict) or not {"name", "field"} <= set(entry) <= {"name", "field", "choices"}:
            raise ValueError("each argument is an object with name, field and maybe choices")
        if not isinstance(entry["name"], str) or not isinstance(entry["field"], str):
            raise ValueError("an argument's name and field must be text")
        choices = entry.get("choices")
        if choices is not None and not isinstance(choices, dict):
            raise ValueError(f"argument {entry['name'][:64]!r}: choices must be an object")
        arguments.append(ToolArgument(entry["name"], entry["field"], choices))
    return tuple(arguments)


def _rules_from(raw: Any) -> ToolRules:
    keys = {"while_asleep", "min_interval_s", "max_duration_s", "confirm", "timeout_s"}
    if not isinstance(raw, dict) or set(raw) != keys:
        raise ValueError(f"rules must be an object with exactly {sorted(keys)}")
    for key in ("while_asleep", "confirm"):
        if not isinstance(raw[key], bool):
            raise ValueError(f"rules.{key} must be true or false")
    for key in ("min_interval_s", "max_duration_s", "timeout_s"):
        if isinstance(raw[key], bool) or not isinstance(raw[key], (int, float)):
            raise ValueError(f"rules.{key} must be a number")
    return ToolRules(
        raw["while_asleep"],
        float(raw["min_interval_s"]),
        float(raw["max_duration_s"]),
        float(raw["timeout_s"]),
        raw["confirm"],
    )


def _feedback_from(raw: Any) -> FeedbackRule | None:
    if raw is None:
        return None
    if not isinstance(raw, dict) or set(raw) != {"every_s", "fields"}:
        raise ValueError("feedback must be null or an object with every_s and fields")
    every, fields = raw["every_s"], raw["fields"]
    if isinstance(every, bool) or not isinstance(every, (int, float)):
        raise ValueError("feedback.every_s must be a number")
    if not isinstance(fields, list) or not all(isinstance(f, str) for f in fields):
        raise ValueError("feedback.fields must be a list of texts")
    return FeedbackRule(float(every), tuple(fields))


# --- building from tools.yaml ------------------------------------------------------------------


def build_catalog(config: ToolsConfig, describe: Callable[[str], Interface]) -> Catalog:
    """tools.yaml + the installed interfaces (`describe`) → the catalog; ToolsConfigError (naming the
    tool and the key) when the file does not fit the interfaces."""
    tools = tuple(_build_tool(tool, describe) for tool in config.tools)
    try:
        check_catalog(tools)
    except ValueError as error:
        raise ToolsConfigError(f"the catalog is inconsistent: {error}") from None
    catalog = Catalog(tools)
    if len(catalog.to_json()) > MAX_CATALOG_CHARS:
        raise ToolsConfigError(f"the tools' catalog is larger than {MAX_CATALOG_CHARS} characters")
    return catalog


def _build_tool(tool: ToolConfig, describe: Callable[[str], Interface]) -> RobotTool:
    def error(key: str, problem: str) -> ToolsConfigError:
        return ToolsConfigError(f"tool {tool.name!r}: {key}: {problem}")

    if tool.kind == "command":
        arguments = tuple(ToolArgument(a.name, "", a.choices) for a in tool.arguments or ())
        properties = {
            a.name: choices_schema(list(a.choices or {}), a.description) for a in tool.arguments or ()
        }
        parameters = parameters_schema(properties, list(properties), tool.rules.confirm)
        return RobotTool(
            tool.name, tool.description or f"Robot command {tool.command}", tool.kind, "", "",
            parameters, {}, arguments, tool.command, tool.rules, None, tool.spoken,
        )  # fmt: skip
    try:
        interface = describe(tool.type)
    except (InterfaceError, ValueError, LookupError) as problem:
        raise error("type", str(problem)) from None
    expected = {"action": "action", "service": "srv", "topic": "msg"}[tool.kind]
    if interface.kind != expected:
        raise error(
            "type", f"{interface.type} is not {'an' if tool.kind == 'action' else 'a'} {tool.kind} type"
        )
    message = interface.part(INPUT_PART[expected])
    try:
        fixed = validate(message_schema(message), tool.fixed, "field") if tool.fixed else {}
    except (ToolArgumentError, SchemaProblem) as problem:
        raise error("fixed", str(problem)) from None
    built = (
        [_build_argument(a, message, error) for a in tool.arguments] if tool.arguments is not None else None
    )
    if built is None:  # every top-level field not fixed, filled by the model if it wants
        built = []
        for ros_field in message.fields:
            if ros_field.name in fixed:
                continue
            try:
                schema = field_schema(ros_field)
            except SchemaProblem as problem:
                raise error("arguments", f"{problem} (declare the arguments the model may set)") from None
            built.append((ToolArgument(ros_field.name, ros_field.name), schema, False))
    if len(built) > MAX_TOOL_ARGUMENTS:
        raise error("arguments", f"{len(built)} fields: declare the few arguments the model may set")
    names = {argument.name for argument, _, _ in built}
    if CONFIRMED in names:
        raise error(
            "arguments", f"{CONFIRMED!r} is reserved; the interface has such a field: declare arguments"
        )
    _refuse_overlaps(fixed, [argument for argument, _, _ in built], error)
    properties = {argument.name: schema for argument, schema, _ in built}
    required = [argument.name for argument, _, needed in built if needed]
    parameters = parameters_schema(properties, required, tool.rules.confirm)
    feedback = _feedback(tool, interface, error)
    description = tool.description or f"Call the ROS {tool.kind} {tool.ros_name} ({tool.type})"
    # Phrases made from the name never call a tool with fields left to their defaults (a goal at 0, 0)
    open_fields = any(argument.choices is None for argument, _, _ in built)
    spoken = () if tool.spoken_default and open_fields else tool.spoken
    return RobotTool(
        tool.name, description, tool.kind, tool.ros_name, tool.type, parameters, fixed,
        tuple(argument for argument, _, _ in built), "", tool.rules, feedback, spoken,
    )  # fmt: skip


def _build_argument(
    argument: ArgumentConfig, message: Message, error: Callable[[str, str], ToolsConfigError]
) -> tuple[ToolArgument, dict[str, Any], bool]:
    """(how it maps, its schema, required) of a declared argument: every declared one is required."""
    key = f"arguments.{argument.name}"
    found: Field | None = None
    parent = message
    if argument.field:
        found = message.find(argument.field)
        if found is None:
            known = ", ".join(f.name for f in message.fields) or "none"
            raise error(
                f"{key}.field", f"{message.type} has no field {argument.field!r} (its fields: {known})"
            )
        parent_path = argument.field.rpartition(".")[0]
        holder = message.find(parent_path) if parent_path else None
        parent = holder.message if holder is not None and holder.message is not None else message
    try:
        if argument.choices is None:
            assert found is not None  # config: an argument without choices has a field
            return ToolArgument(argument.name, argument.field), argument_schema(found, argument, parent), True
        schema = field_schema(found) if found is not None else message_schema(message)
    except SchemaProblem as problem:
        raise error(key, str(problem)) from None
    choices: dict[str, Any] = {}
    for name, value in argument.choices.items():
        try:
            choices[name] = validate(schema, value, "field")
        except ToolArgumentError as problem:
            raise error(f"{key}.choices.{name}", str(problem)) from None
    mapping = ToolArgument(argument.name, argument.field, choices)
    return mapping, choices_schema(list(choices), argument.description), True


def _refuse_overlaps(
    fixed: dict[str, Any], arguments: list[ToolArgument], error: Callable[[str, str], ToolsConfigError]
) -> None:
    fixed_paths = set(leaf_paths(fixed)) if fixed else set()
    claimed: list[tuple[str, set[tuple[str, ...]]]] = []
    for argument in arguments:
        paths = argument_paths(argument)
        hit = overlap(paths, fixed_paths)
        if hit:
            raise error(f"arguments.{argument.name}", f"would set {'.'.join(hit)!r}, which is fixed")
        for other, other_paths in claimed:
            hit = overlap(paths, other_paths)
            if hit:
                raise error(f"arguments.{argument.name}", f"sets {'.'.join(hit)!r}, like argument {other!r}")
        claimed.append((argument.name, paths))


def _feedback(
    tool: ToolConfig, interface: Interface, error: Callable[[str, str], ToolsConfigError]
) -> FeedbackRule | None:
    if tool.feedback is None or interface.kind != "action":
        return None
    part = interface.part("feedback")
    fields = tool.feedback.fields or tuple(f.name for f in part.fields)
    for path in fields:
        if part.find(path) is None:
            known = ", ".join(f.name for f in part.fields) or "none"
            raise error("feedback.fields", f"{part.type} has no field {path!r} (its fields: {known})")
    return FeedbackRule(tool.feedback.every_s, fields)
