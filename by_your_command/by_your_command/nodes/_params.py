"""Declare ROS parameters from a frozen dataclass: the dataclass holds the one set of defaults."""

from __future__ import annotations

import dataclasses
import typing
from typing import Any, TypeVar

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

ConfigT = TypeVar("ConfigT")

_SUPPORTED = (bool, int, float, str)


def declare_config(node: Node, config_type: type[ConfigT], prefix: str = "") -> ConfigT:
    """Declare one ROS parameter per dataclass field and build the config from their values.

    Field types must be bool, int, float, str or list[str]/list[float]/list[int]; the
    field's docstring-style metadata `help` becomes the parameter description.
    Values are validated by the dataclass's own __post_init__ (if any), so a bad
    parameter fails at startup with the dataclass's message.
    """
    if not dataclasses.is_dataclass(config_type):
        raise TypeError(f"{config_type!r} is not a dataclass")
    hints = typing.get_type_hints(config_type)
    values: dict[str, Any] = {}
    for field in dataclasses.fields(config_type):
        if field.default is not dataclasses.MISSING:
            default = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        else:
            raise TypeError(f"{config_type.__name__}.{field.name} needs a default to become a parameter")
        hint = hints[field.name]
        descriptor = ParameterDescriptor(description=field.metadata.get("help", ""))
        name = f"{prefix}{field.name}"
        value = node.declare_parameter(name, _to_ros(default, hint), descriptor).value
        values[field.name] = _from_ros(value, hint, name)
    return config_type(**values)


_ARRAY_TYPES = {
    str: Parameter.Type.STRING_ARRAY,
    float: Parameter.Type.DOUBLE_ARRAY,
    int: Parameter.Type.INTEGER_ARRAY,
    bool: Parameter.Type.BOOL_ARRAY,
}


def _to_ros(value: Any, hint: Any) -> Any:
    origin = typing.get_origin(hint)
    if origin in (list, tuple):
        if not value:  # ROS cannot infer the type of an empty list: declare it by type
            element = typing.get_args(hint)[0] if typing.get_args(hint) else str
            return _ARRAY_TYPES[element]
        return list(value)
    return value


def _from_ros(value: Any, hint: Any, name: str) -> Any:
    origin = typing.get_origin(hint)
    if origin in (list, tuple):
        items = list(value) if value is not None else []
        return tuple(items) if origin is tuple else items
    if hint is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if hint in _SUPPORTED and not isinstance(value, hint):
        raise TypeError(f"parameter {name!r} must be {hint.__name__}, got {type(value).__name__}")
    return value
