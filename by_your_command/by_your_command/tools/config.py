"""tools.yaml → ToolsConfig: the robot's actions, services, topics and commands the model may call.

Only the file's own rules are checked here (keys, types, ranges, names, templates); whether the
fields exist in the interfaces is build_catalog's job (it needs the installed types). Every error
names the tool and the key.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml

from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.protocol import MAX_CALL_TIMEOUT_S, normalize_interface, normalize_type
from by_your_command.tools.errors import ToolsConfigError
from by_your_command.tools.values import ValueProblem, check_path, check_plain, expand

__all__ = [
    "ArgumentConfig",
    "FeedbackRule",
    "ToolConfig",
    "ToolRules",
    "ToolsConfig",
    "ToolsConfigError",
    "load_tools_config",
    "parse_tools_config",
]

ToolKind = Literal["action", "service", "topic", "command"]
KINDS: tuple[ToolKind, ...] = ("action", "service", "topic", "command")
TOOL_NAME = re.compile(r"^[a-zA-Z][a-zA-Z0-9_]{0,63}$")
RESERVED_NAMES = frozenset({"robot_command"})  # the agents' own tool
CONFIRMED = "confirmed"  # the argument a confirm tool's model must pass
PLACEHOLDER = re.compile(r"\{([^{}]*)\}")
COMMAND_VALUE = re.compile(r"^[A-Za-z0-9_.+@:\- ]{1,64}$")  # no ',' ';' or newline: one command only
MAX_TOOLS = 64
MAX_ARGUMENTS = 16
MAX_CHOICES = 256
MAX_CHOICE_CHARS = 64
MAX_SPOKEN = 32  # templates per tool
MAX_SPOKEN_FORMS = 1024  # phrases per tool, every template × every choice
MAX_TEMPLATE_CHARS = 200
MAX_COMMAND_CHARS = 200  # robot_command's bound
MAX_DESCRIPTION_CHARS = 1000
MAX_FEEDBACK_FIELDS = 16
MAX_DURATION_S = 86_400.0
MAX_BOUND_ITEMS = 1_000_000

TOOL_KEYS = frozenset(
    {
        "description",
        *KINDS,
        "type",
        "fixed",
        "arguments",
        "feedback",
        "while_asleep",
        "min_interval_s",
        "max_duration_s",
        "timeout_s",
        "confirm",
        "spoken",
    }
)
ARGUMENT_KEYS = frozenset(
    {"description", "field", "choices", "minimum", "maximum", "max_length", "max_items"}
)


@dataclass(frozen=True)
class ToolRules:
    while_asleep: bool = False  # callable while the robot sleeps or is muted
    min_interval_s: float = 0.0  # refused when called again sooner
    max_duration_s: float = 60.0  # an action's goal is cancelled after this
    timeout_s: float = 10.0  # waiting for the server, the goal's acceptance, a service's response
    confirm: bool = False  # the model must pass confirmed: true (after a spoken yes)


@dataclass(frozen=True)
class FeedbackRule:
    every_s: float = 5.0  # at most one progress note this often
    fields: tuple[str, ...] = ()  # dotted feedback fields summarised; () = every top-level field


@dataclass(frozen=True)
class ArgumentConfig:
    name: str
    description: str = ""
    field: str = ""  # dotted path the value (or the choice's value) goes to; "" = the choice's own paths
    # name → value: a nested dict of fields (merged at `field`, or at the top), or a plain value set
    # at `field` (a command tool's value for its template); None: the model fills `field` itself
    choices: dict[str, Any] | None = None
    minimum: float | None = None
    maximum: float | None = None
    max_length: int | None = None
    max_items: int | None = None


@dataclass(frozen=True)
class ToolConfig:
    name: str
    kind: ToolKind
    description: str = ""
    ros_name: str = ""  # "" for command tools
    type: str = ""  # normalised pkg/action/T, pkg/srv/T, pkg/msg/T; "" for command tools
    fixed: dict[str, Any] = field(default_factory=dict)  # nested fields always set
    arguments: tuple[ArgumentConfig, ...] | None = None  # None: every top-level field not fixed
    command: str = ""  # command tools: the template, e.g. "pan@{direction}"
    rules: ToolRules = ToolRules()
    feedback: FeedbackRule | None = None  # actions only
    spoken: tuple[str, ...] = ()
    spoken_default: bool = False  # the phrases were made from the name (default_spoken)


@dataclass(frozen=True)
class ToolsConfig:
    tools: tuple[ToolConfig, ...] = ()


class _Where:
    """Builds "tool 'go_to': arguments.place.choices: …" errors."""

    def __init__(self, tool: str) -> None:
        self.tool = tool

    def error(self, key: str, problem: str) -> ToolsConfigError:
        return ToolsConfigError(f"tool {self.tool!r}: {key}: {problem}")


class _NoDuplicatesLoader(yaml.SafeLoader):
    """YAML keeps the last of two equal keys silently; a tool declared twice must be an error."""


def _mapping(loader: _NoDuplicatesLoader, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
    loader.flatten_mapping(node)
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        try:
            duplicate = key in seen
        except TypeError:
            raise yaml.constructor.ConstructorError(
                None, None, f"unhashable key {key!r}", key_node.start_mark
            ) from None
        if duplicate:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_NoDuplicatesLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)


def load_tools_config(path: Path) -> ToolsConfig:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise ToolsConfigError(f"cannot read tools config {path}: {error}") from None
    try:
        data = yaml.load(text, Loader=_NoDuplicatesLoader)  # noqa: S506 (a SafeLoader subclass)
    except yaml.YAMLError as error:
        raise ToolsConfigError(f"tools config {path} is not valid YAML: {error}") from None
    return parse_tools_config(data)


def parse_tools_config(data: Any) -> ToolsConfig:
    if data is None:
        return ToolsConfig()
    if not isinstance(data, dict) or set(data) - {"tools"}:
        raise ToolsConfigError("the tools config must be a mapping with one key, 'tools'")
    tools = data.get("tools") or {}
    if not isinstance(tools, dict):
        raise ToolsConfigError("'tools' must be a mapping of tool names to their settings")
    if len(tools) > MAX_TOOLS:
        raise ToolsConfigError(f"'tools' declares {len(tools)} tools, at most {MAX_TOOLS} are allowed")
    parsed: list[ToolConfig] = []
    seen: dict[str, str] = {}
    for name, entry in tools.items():
        if not isinstance(name, str) or not TOOL_NAME.match(name):
            raise ToolsConfigError(
                f"tool {name!r}: invalid name (a letter, then letters, digits or _; at most 64)"
            )
        if name in RESERVED_NAMES:
            raise ToolsConfigError(f"tool {name!r}: the name is reserved for the agents' own tool")
        other = seen.setdefault(name.lower(), name)
        if other != name:
            raise ToolsConfigError(f"tool {name!r}: collides with tool {other!r} (names differ only in case)")
        parsed.append(_tool(name, entry))
    return ToolsConfig(tuple(parsed))


def _tool(name: str, entry: Any) -> ToolConfig:
    where = _Where(name)
    if not isinstance(entry, dict):
        raise ToolsConfigError(f"tool {name!r}: expected a mapping of settings")
    unknown = sorted(str(key) for key in set(entry) - TOOL_KEYS)
    if unknown:
        raise where.error(unknown[0], f"unknown key (expected some of {', '.join(sorted(TOOL_KEYS))})")
    kinds = [kind for kind in KINDS if kind in entry]
    if len(kinds) != 1:
        raise where.error(
            "action|service|topic|command", f"exactly one of them is needed, got {kinds or 'none'}"
        )
    kind = kinds[0]
    description = _text(entry, "description", where, MAX_DESCRIPTION_CHARS, "")
    rules = _rules(entry, where)
    arguments = _arguments(entry.get("arguments"), kind, where) if "arguments" in entry else None
    command = ros_name = type_name = ""
    if kind == "command":
        command = _command_template(entry, arguments, where)
        for key in ("type", "fixed", "feedback"):
            if key in entry:
                raise where.error(key, "command tools have no ROS interface")
    else:
        ros_name = _ros_name(entry, kind, where)
        type_name = _type(entry, kind, where)
    fixed = _fixed(entry, where)
    feedback = _feedback(entry, kind, where)
    spoken = _spoken(entry, arguments, rules, where)
    spoken_default = "spoken" not in entry
    return ToolConfig(
        name, kind, description, ros_name, type_name, fixed, arguments, command, rules, feedback, spoken,
        spoken_default,
    )  # fmt: skip


def _text(entry: dict[str, Any], key: str, where: _Where, limit: int, default: str) -> str:
    value = entry.get(key, default)
    if not isinstance(value, str) or len(value) > limit:
        raise where.error(key, f"expected text of at most {limit} characters, got {_short(value)}")
    return value.strip()


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:60] + "…"


def _number(
    entry: dict[str, Any],
    key: str,
    where: _Where,
    default: float,
    low: float,
    high: float,
    low_open: bool = False,
    prefix: str = "",
) -> float:
    value = entry.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise where.error(prefix + key, f"expected a number of seconds, got {_short(value)}")
    if value < low or (low_open and value == low) or value > high:
        bound = f"> {low:g}" if low_open else f">= {low:g}"
        raise where.error(prefix + key, f"must be {bound} and <= {high:g}, got {value!r}")
    return float(value)


def _flag(entry: dict[str, Any], key: str, where: _Where) -> bool:
    value = entry.get(key, False)
    if not isinstance(value, bool):
        raise where.error(key, f"expected true or false, got {_short(value)}")
    return value


def _rules(entry: dict[str, Any], where: _Where) -> ToolRules:
    defaults = ToolRules()
    return ToolRules(
        while_asleep=_flag(entry, "while_asleep", where),
        min_interval_s=_number(entry, "min_interval_s", where, defaults.min_interval_s, 0.0, MAX_DURATION_S),
        max_duration_s=_number(
            entry, "max_duration_s", where, defaults.max_duration_s, 0.0, MAX_DURATION_S, low_open=True
        ),
        timeout_s=_number(
            entry, "timeout_s", where, defaults.timeout_s, 0.0, MAX_CALL_TIMEOUT_S, low_open=True
        ),
        confirm=_flag(entry, "confirm", where),
    )


def _ros_name(entry: dict[str, Any], kind: str, where: _Where) -> str:
    value = entry[kind]
    if not isinstance(value, str) or len(value) > 256:
        raise where.error(kind, f"expected a ROS name, got {_short(value)}")
    try:
        resolve_topic(value, "/")  # the bridge resolves and allow-lists it like a topic
    except ValueError as error:
        raise where.error(kind, str(error)) from None
    return value


def _type(entry: dict[str, Any], kind: str, where: _Where) -> str:
    value = entry.get("type")
    if not isinstance(value, str):
        raise where.error("type", f"the {kind}'s interface type is needed (pkg/{_middle(kind)}/Type)")
    try:
        if kind == "topic":
            if "/srv/" in value or "/action/" in value:
                raise ValueError(f"a topic needs a message type (pkg/msg/Type), got {value!r}")
            return normalize_type(value)
        return normalize_interface(value, "action" if kind == "action" else "srv")
    except ValueError as error:
        raise where.error("type", str(error)) from None


def _middle(kind: str) -> str:
    return {"action": "action", "service": "srv", "topic": "msg"}[kind]


def _fixed(entry: dict[str, Any], where: _Where) -> dict[str, Any]:
    if entry.get("fixed") is None:
        return {}
    try:
        return expand(entry["fixed"], "fixed")
    except ValueProblem as error:
        raise where.error("fixed", str(error).removeprefix("fixed: ")) from None


def _arguments(raw: Any, kind: str, where: _Where) -> tuple[ArgumentConfig, ...]:
    if raw is None:
        return ()
    if not isinstance(raw, dict):
        raise where.error("arguments", "expected a mapping of argument names to their settings")
    if len(raw) > MAX_ARGUMENTS:
        raise where.error("arguments", f"{len(raw)} arguments, at most {MAX_ARGUMENTS} are allowed")
    return tuple(_argument(name, spec, kind, where) for name, spec in raw.items())


def _argument(name: Any, spec: Any, kind: str, where: _Where) -> ArgumentConfig:
    key = f"arguments.{name}"
    if not isinstance(name, str) or not TOOL_NAME.match(name):
        raise where.error(key, "invalid argument name (a letter, then letters, digits or _; at most 64)")
    if name == CONFIRMED:
        raise where.error(key, "'confirmed' is reserved (set confirm: true instead)")
    if not isinstance(spec, dict):
        raise where.error(key, "expected a mapping (field, choices, description, bounds)")
    unknown = sorted(str(k) for k in set(spec) - ARGUMENT_KEYS)
    if unknown:
        raise where.error(
            f"{key}.{unknown[0]}", f"unknown key (expected some of {', '.join(sorted(ARGUMENT_KEYS))})"
        )
    description = spec.get("description", "")
    if not isinstance(description, str) or len(description) > MAX_DESCRIPTION_CHARS:
        raise where.error(
            f"{key}.description", f"expected text of at most {MAX_DESCRIPTION_CHARS} characters"
        )
    field_path = spec.get("field", "")
    if not isinstance(field_path, str):
        raise where.error(f"{key}.field", f"expected a dotted field path, got {_short(field_path)}")
    if field_path:
        if kind == "command":
            raise where.error(f"{key}.field", "command tools have no message fields")
        try:
            check_path(field_path)
        except ValueProblem as error:
            raise where.error(f"{key}.field", str(error)) from None
    choices = _choices(spec["choices"], field_path, kind, where, key) if "choices" in spec else None
    bounds = {bound: spec.get(bound) for bound in ("minimum", "maximum", "max_length", "max_items")}
    given = [bound for bound, value in bounds.items() if value is not None]
    if choices is None and not field_path:
        raise where.error(key, "needs 'choices' or a 'field' the model fills")
    if choices is not None and given:
        raise where.error(f"{key}.{given[0]}", "bounds apply to 'field' arguments, not to choices")
    for bound in ("minimum", "maximum"):
        value = bounds[bound]
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
        ):
            raise where.error(f"{key}.{bound}", f"expected a finite number, got {_short(value)}")
    for bound in ("max_length", "max_items"):
        value = bounds[bound]
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_BOUND_ITEMS
        ):
            raise where.error(
                f"{key}.{bound}", f"expected a whole number 0..{MAX_BOUND_ITEMS}, got {_short(value)}"
            )
    low, high = bounds["minimum"], bounds["maximum"]
    if low is not None and high is not None and low > high:
        raise where.error(f"{key}.minimum", f"{low} is above the maximum {high}")
    return ArgumentConfig(
        name, description.strip(), field_path, choices, low, high, bounds["max_length"], bounds["max_items"]
    )


def _choices(raw: Any, field_path: str, kind: str, where: _Where, key: str) -> dict[str, Any]:
    key = f"{key}.choices"
    if isinstance(raw, list):
        pairs = [(name, name) for name in raw]
    elif isinstance(raw, dict):
        pairs = list(raw.items())
    else:
        raise where.error(key, "expected a list of names or a mapping of names to values")
    if not pairs:
        raise where.error(key, "at least one choice is needed")
    if len(pairs) > MAX_CHOICES:
        raise where.error(key, f"{len(pairs)} choices, at most {MAX_CHOICES} are allowed")
    choices: dict[str, Any] = {}
    seen: dict[str, str] = {}
    for name, value in pairs:
        problem = choice_name_problem(name)
        if problem:
            raise where.error(key, f"{_short(name)}: {problem}")
        other = seen.setdefault(name.lower(), name)
        if other != name or name in choices:
            raise where.error(key, f"{name!r} is listed twice (names differ only in case?)")
        choices[name] = _choice_value(value, field_path, kind, where, f"{key}.{name}")
    return choices


def choice_name_problem(name: Any) -> str:
    """Why `name` cannot be a choice ("" if it can): it is spoken, shown and put in an enum."""
    if not isinstance(name, str) or not name or len(name) > MAX_CHOICE_CHARS:
        return f"a choice name is text of 1..{MAX_CHOICE_CHARS} characters"
    if name != name.strip() or "{" in name or "}" in name or not name.isprintable():
        return "a choice name has no braces, control characters or surrounding spaces"
    return ""


def _choice_value(value: Any, field_path: str, kind: str, where: _Where, key: str) -> Any:
    if kind == "command":
        if (
            isinstance(value, bool)
            or not isinstance(value, (str, int, float))
            or not COMMAND_VALUE.match(str(value))
        ):
            raise where.error(
                key, "a command tool's value is a short word (letters, digits, _ . + @ : - space)"
            )
        return str(value)
    try:
        if isinstance(value, dict):
            return expand(value, key)
        if not field_path:
            raise ValueProblem(
                "a mapping of field paths to values is needed (or give the argument a 'field')"
            )
        check_plain(value, key)
    except ValueProblem as error:
        raise where.error(key, str(error).removeprefix(f"{key}: ")) from None
    return value


def _command_template(
    entry: dict[str, Any], arguments: tuple[ArgumentConfig, ...] | None, where: _Where
) -> str:
    template = entry["command"]
    if (
        not isinstance(template, str)
        or not template.strip()
        or len(template) > MAX_COMMAND_CHARS
        or not template.isprintable()
    ):
        raise where.error("command", f"expected one line of text of at most {MAX_COMMAND_CHARS} characters")
    names = {argument.name for argument in arguments or ()}
    try:
        used = template_names(template)
    except ValueError as error:
        raise where.error("command", str(error)) from None
    missing = sorted(used - names)
    if missing:
        raise where.error("command", f"{{{missing[0]}}} is not an argument of this tool")
    unused = sorted(names - used)
    if unused:
        raise where.error(f"arguments.{unused[0]}", "not used in the command template")
    return template.strip()


def template_names(template: str) -> set[str]:
    """The `{name}` placeholders of a template; stray braces or odd names are a ValueError."""
    names = set(PLACEHOLDER.findall(template))
    if "{" in PLACEHOLDER.sub("", template) or "}" in PLACEHOLDER.sub("", template):
        raise ValueError(f"stray brace in {template!r}")
    bad = sorted(name for name in names if not TOOL_NAME.match(name))
    if bad:
        raise ValueError(f"{{{bad[0]}}} is not an argument name")
    return names


def _feedback(entry: dict[str, Any], kind: str, where: _Where) -> FeedbackRule | None:
    if "feedback" not in entry:
        return None
    if kind != "action":
        raise where.error("feedback", "only actions have feedback")
    raw = entry["feedback"]
    if raw is None:
        return None
    if not isinstance(raw, dict) or set(raw) - {"every_s", "fields"}:
        raise where.error("feedback", "expected a mapping with every_s and fields")
    every = _number(
        raw, "every_s", where, FeedbackRule().every_s, 0.0, MAX_DURATION_S, low_open=True, prefix="feedback."
    )
    fields = raw.get("fields") or []
    if not isinstance(fields, list) or len(fields) > MAX_FEEDBACK_FIELDS:
        raise where.error("feedback.fields", f"expected a list of at most {MAX_FEEDBACK_FIELDS} field paths")
    for path in fields:
        try:
            check_path(path)
        except ValueProblem as error:
            raise where.error("feedback.fields", str(error)) from None
    if len(set(fields)) != len(fields):
        raise where.error("feedback.fields", "a field is listed twice")
    return FeedbackRule(every, tuple(fields))


def default_spoken(name: str, arguments: tuple[ArgumentConfig, ...] | None, rules: ToolRules) -> list[str]:
    """The offline agent's phrases for a tool that declares none: its name said as words, with the
    name of one of its choices after it ("go_to" + place → "go to the kitchen", "dock" → "dock").
    Only for tools whose every argument is named values (one at most) and that need no yes; a tool
    whose arguments are left to the interface keeps them only if it has no field to fill
    (`spoken_default`: the catalog checks that against the interface)."""
    words = " ".join(name.split("_")).strip()
    if not words or rules.confirm:
        return []
    named = [argument for argument in arguments or () if argument.choices is not None]
    if len(named) != len(arguments or ()) or len(named) > 1:
        return []
    if not named:
        return [words]
    return [f"{words} the {{{named[0].name}}}", f"{words} {{{named[0].name}}}"]


def _spoken(
    entry: dict[str, Any], arguments: tuple[ArgumentConfig, ...] | None, rules: ToolRules, where: _Where
) -> tuple[str, ...]:
    raw = entry.get("spoken")
    if raw is None:
        raw = default_spoken(where.tool, arguments, rules)
    if isinstance(raw, str):
        raw = [raw]
    if not isinstance(raw, list) or len(raw) > MAX_SPOKEN:
        raise where.error("spoken", f"expected a list of at most {MAX_SPOKEN} phrases")
    if raw and rules.confirm:
        raise where.error(
            "spoken", "a confirm tool needs the user's spoken yes: it cannot be a spoken phrase"
        )
    by_name = {argument.name: argument for argument in arguments or ()}
    templates: list[str] = []
    total = 0
    for template in raw:
        if not isinstance(template, str) or not template.strip() or len(template) > MAX_TEMPLATE_CHARS:
            raise where.error(
                "spoken", f"expected phrases of 1..{MAX_TEMPLATE_CHARS} characters, got {_short(template)}"
            )
        try:
            used = template_names(template)
        except ValueError as error:
            raise where.error("spoken", str(error)) from None
        for name in sorted(used):
            if name not in by_name:
                raise where.error("spoken", f"{template!r}: {{{name}}} is not an argument of this tool")
            if by_name[name].choices is None:
                raise where.error("spoken", f"{template!r}: {{{name}}} has no choices to say")
        missing = sorted(set(by_name) - used)
        if missing:
            raise where.error("spoken", f"{template!r} does not say the argument {missing[0]!r}")
        forms = 1
        for name in used:
            forms *= len(by_name[name].choices or {})
        total += forms
        if total > MAX_SPOKEN_FORMS:
            raise where.error(
                "spoken", f"the phrases make {total}+ forms, at most {MAX_SPOKEN_FORMS} are allowed"
            )
        if template.strip() in templates:
            raise where.error("spoken", f"{template!r} is listed twice")
        templates.append(template.strip())
    return tuple(templates)
