"""Whether a catalog tool is consistent: the same rules for one the bridge built from tools.yaml
and one an agent received over the bridge (untrusted), so a tool that passes can be offered,
validated, built and spoken without surprises."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from by_your_command.bridge.names import resolve_topic
from by_your_command.bridge.protocol import MAX_CALL_TIMEOUT_S, normalize_interface, normalize_type
from by_your_command.tools.arguments import check_schema
from by_your_command.tools.config import (
    COMMAND_VALUE,
    CONFIRMED,
    MAX_CHOICES,
    MAX_COMMAND_CHARS,
    MAX_DESCRIPTION_CHARS,
    MAX_DURATION_S,
    MAX_FEEDBACK_FIELDS,
    MAX_SPOKEN,
    MAX_SPOKEN_FORMS,
    MAX_TEMPLATE_CHARS,
    RESERVED_NAMES,
    TOOL_NAME,
    choice_name_problem,
    template_names,
)
from by_your_command.tools.values import ValueProblem, check_path, check_plain, leaf_paths, overlap

if TYPE_CHECKING:
    from by_your_command.tools.catalog import RobotTool, ToolArgument

MAX_TOOL_ARGUMENTS = 64  # declared ones are at most 16; derived from an interface's fields, 64
MAX_NAME_CHARS = 256


def _a(kind: str) -> str:
    return f"an {kind}" if kind[:1] in "aeiou" else f"a {kind}"


def argument_paths(argument: ToolArgument) -> set[tuple[str, ...]]:
    """The field paths an argument may set (a model-filled field: that whole subtree)."""
    base = tuple(argument.field.split(".")) if argument.field else ()
    if argument.choices is None:
        return {base}
    paths: set[tuple[str, ...]] = set()
    for value in argument.choices.values():
        if isinstance(value, dict) and value:
            paths |= {base + path for path in leaf_paths(value)}
        else:
            paths.add(base)
    return paths


def check_tool(tool: RobotTool) -> None:
    """ValueError (naming the tool) unless the tool is consistent."""
    try:
        _check(tool)
    except ValueProblem as problem:
        raise ValueError(f"tool {tool.name[:64]!r}: {problem}") from None
    except ValueError as problem:
        raise ValueError(f"tool {tool.name[:64]!r}: {problem}") from None


def _check(tool: RobotTool) -> None:
    if not TOOL_NAME.match(tool.name) or tool.name in RESERVED_NAMES:
        raise ValueError("invalid or reserved name")
    if len(tool.description) > MAX_DESCRIPTION_CHARS:
        raise ValueError("description too long")
    _check_target(tool)
    _check_rules(tool)
    check_schema(tool.parameters)
    check_plain(tool.fixed, "fixed")
    _check_arguments(tool)
    _check_spoken(tool)


def _check_target(tool: RobotTool) -> None:
    if tool.kind == "command":
        if tool.ros_name or tool.type or tool.fixed or tool.feedback is not None:
            raise ValueError("a command tool has no ROS name, type, fixed fields or feedback")
        if not tool.command or len(tool.command) > MAX_COMMAND_CHARS or not tool.command.isprintable():
            raise ValueError("a command tool needs its command template (one short line)")
        return
    if tool.command:
        raise ValueError(f"{_a(tool.kind)} tool has no command template")
    if len(tool.ros_name) > MAX_NAME_CHARS or len(tool.type) > MAX_NAME_CHARS:
        raise ValueError(f"ros_name and type are at most {MAX_NAME_CHARS} characters")
    resolve_topic(tool.ros_name, "/")
    if tool.kind == "topic":
        normalized = normalize_type(tool.type)
    else:
        normalized = normalize_interface(tool.type, "action" if tool.kind == "action" else "srv")
    if normalized != tool.type:
        raise ValueError(f"type {tool.type!r} is not {_a(tool.kind)} type")
    if tool.feedback is not None:
        if tool.kind != "action":
            raise ValueError("only actions have feedback")
        if not 0 < tool.feedback.every_s <= MAX_DURATION_S or len(tool.feedback.fields) > MAX_FEEDBACK_FIELDS:
            raise ValueError("feedback: every_s or fields out of range")
        for path in tool.feedback.fields:
            check_path(path)


def _check_rules(tool: RobotTool) -> None:
    rules = tool.rules
    numbers = (rules.min_interval_s, rules.max_duration_s, rules.timeout_s)
    if not all(math.isfinite(value) for value in numbers):
        raise ValueError("rules: numbers must be finite")
    if not (
        0 <= rules.min_interval_s <= MAX_DURATION_S
        and 0 < rules.max_duration_s <= MAX_DURATION_S
        and 0 < rules.timeout_s <= MAX_CALL_TIMEOUT_S
    ):
        raise ValueError("rules: a duration is out of range")


def _check_arguments(tool: RobotTool) -> None:
    properties: dict[str, Any] = tool.parameters["properties"]
    names = [argument.name for argument in tool.arguments]
    if len(names) > MAX_TOOL_ARGUMENTS or len(set(names)) != len(names):
        raise ValueError("too many arguments, or one listed twice")
    expected = set(names) | ({CONFIRMED} if tool.rules.confirm else set())
    if set(properties) != expected or CONFIRMED in names:
        raise ValueError("the schema's properties do not match the arguments")
    if tool.rules.confirm and (
        properties[CONFIRMED].get("type") != "boolean" or CONFIRMED not in tool.parameters["required"]
    ):
        raise ValueError("a confirm tool's schema needs a required boolean 'confirmed'")
    fixed_paths = set(leaf_paths(tool.fixed)) if tool.fixed else set()
    claimed: list[set[tuple[str, ...]]] = []
    for argument in tool.arguments:
        _check_argument(tool, argument, properties[argument.name])
        paths = argument_paths(argument)
        if overlap(paths, fixed_paths) or any(overlap(paths, other) for other in claimed):
            raise ValueError(f"argument {argument.name!r} sets a field that is fixed or set by another")
        claimed.append(paths)
    if tool.kind == "command":
        used = template_names(tool.command)
        with_choices = {a.name for a in tool.arguments if a.choices is not None}
        if used != set(names) or not used <= with_choices:
            raise ValueError("the command template must use exactly the arguments, all with choices")
        longest = len(tool.command)
        for argument in tool.arguments:
            widest = max(len(str(value)) for value in (argument.choices or {"": ""}).values())
            longest += tool.command.count(f"{{{argument.name}}}") * (widest - len(argument.name) - 2)
        if longest > MAX_COMMAND_CHARS:
            raise ValueError(f"the command can be longer than {MAX_COMMAND_CHARS} characters")


def _check_argument(tool: RobotTool, argument: ToolArgument, schema: dict[str, Any]) -> None:
    where = f"argument {argument.name[:64]!r}"
    if not TOOL_NAME.match(argument.name):
        raise ValueError(f"{where}: invalid name")
    if argument.field:
        if tool.kind == "command":
            raise ValueError(f"{where}: a command tool has no fields")
        check_path(argument.field)
    if argument.choices is None:
        if not argument.field:
            raise ValueError(f"{where}: neither choices nor a field")
        return
    if not 0 < len(argument.choices) <= MAX_CHOICES:
        raise ValueError(f"{where}: 1..{MAX_CHOICES} choices")
    if schema.get("type") != "string" or schema.get("enum") != list(argument.choices):
        raise ValueError(f"{where}: its schema must be the enum of its choices")
    for name, value in argument.choices.items():
        problem = choice_name_problem(name)
        if problem:
            raise ValueError(f"{where}: {problem}")
        if tool.kind == "command":
            if not isinstance(value, str) or not COMMAND_VALUE.match(value):
                raise ValueError(f"{where}: a command value must be a short word")
        elif not argument.field and not isinstance(value, dict):
            raise ValueError(f"{where}: a choice without a field must be an object of fields")
        check_plain(value, f"{where}.{name}")


def _check_spoken(tool: RobotTool) -> None:
    if len(tool.spoken) > MAX_SPOKEN:
        raise ValueError(f"at most {MAX_SPOKEN} spoken phrases")
    if tool.spoken and tool.rules.confirm:
        raise ValueError("a confirm tool cannot have spoken phrases")
    by_name = {argument.name: argument for argument in tool.arguments}
    required = set(tool.parameters["required"])
    total = 0
    for template in tool.spoken:
        if not template.strip() or len(template) > MAX_TEMPLATE_CHARS or not template.isprintable():
            raise ValueError("a spoken phrase is one short line")
        used = template_names(template)
        if not all(name in by_name and by_name[name].choices is not None for name in used):
            raise ValueError(f"spoken {template!r}: a placeholder is not an argument with choices")
        if not required <= used:
            raise ValueError(f"spoken {template!r} does not say every required argument")
        forms = 1
        for name in used:
            forms *= len(by_name[name].choices or {})
        total += forms
        if total > MAX_SPOKEN_FORMS:
            raise ValueError(f"the spoken phrases make more than {MAX_SPOKEN_FORMS} forms")
