"""The model's arguments: parsed, checked against the tool's schema, turned into the request.

The validator knows exactly the JSON Schema subset tools/schema.py writes (no jsonschema
dependency: the schemas come over the bridge, so `check_schema` first makes sure a catalog's
schema is within that subset and bounded). Error texts say which argument is wrong and why: the
model reads them and may tell the user.
"""

from __future__ import annotations

import base64
import binascii
import copy
import json
import math
from typing import Any

from by_your_command.tools.errors import ToolArgumentError
from by_your_command.tools.values import MAX_DEPTH, depth_of, merge_into, placed

MAX_ARGUMENTS_CHARS = 262_144  # the model writes a few hundred; a huge blob is a mistake
MAX_SCHEMA_NODES = 20_000
MAX_ENUM = 256
MAX_SHOWN = 12  # enum names listed in an error
TYPES = ("object", "array", "string", "integer", "number", "boolean")
_KEYS = {
    "object": {"properties", "required", "additionalProperties"},
    "array": {"items", "minItems", "maxItems"},
    "string": {"enum", "minLength", "maxLength", "contentEncoding"},
    "integer": {"minimum", "maximum"},
    "number": {"minimum", "maximum"},
    "boolean": set(),
}
_WHAT = {
    "object": "an object",
    "array": "a list",
    "string": "text",
    "integer": "a whole number",
    "number": "a number",
    "boolean": "true or false",
}


def _show(value: Any) -> str:
    if isinstance(value, (dict, list)):
        return f"{'an object' if isinstance(value, dict) else 'a list'} of {len(value)}"
    if value is None:
        return "null"
    text = json.dumps(value) if isinstance(value, (str, bool)) else repr(value)
    return text if len(text) <= 40 else text[:40] + "…"


def parse_arguments(arguments_json: str) -> dict[str, Any]:
    """The model's arguments text → a dict (empty text means no arguments)."""
    if not isinstance(arguments_json, str):
        raise ToolArgumentError("the arguments must be JSON text")
    if len(arguments_json) > MAX_ARGUMENTS_CHARS:
        raise ToolArgumentError(f"the arguments are too long ({len(arguments_json)} characters)")
    if not arguments_json.strip():
        return {}
    try:
        data = json.loads(arguments_json, parse_constant=_no_constant)
    except RecursionError:
        raise ToolArgumentError("the arguments are nested too deeply") from None
    except ValueError as error:
        raise ToolArgumentError(f"the arguments are not valid JSON ({error})") from None
    if not isinstance(data, dict):
        raise ToolArgumentError(f"the arguments must be a JSON object, not {_show(data)}")
    return data


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number")


def validate(schema: dict[str, Any], value: Any, label: str = "argument") -> Any:
    """`value` checked against a schema (the tool's parameters, or a field's); returns it
    normalised (whole numbers written as 2.0 become 2). ToolArgumentError names the argument
    (`label` 'field' for a file's values) and says what is wrong."""
    if depth_of(value) > MAX_DEPTH:
        raise ToolArgumentError(f"the {label}s are nested more than {MAX_DEPTH} deep")
    return _Checker(label).check(schema, value, "")


def _number_text(value: float) -> str:
    return str(value) if isinstance(value, int) else f"{value:g}"


class _Checker:
    def __init__(self, label: str) -> None:
        self.label = label

    def where(self, path: str) -> str:
        return f"{self.label} {path!r}" if path else f"the {self.label}s"

    def check(self, schema: dict[str, Any], value: Any, path: str) -> Any:
        kind = schema["type"]
        where = self.where(path)
        if kind == "boolean":
            if not isinstance(value, bool):
                raise ToolArgumentError(f"{where} must be true or false, not {_show(value)}")
            return value
        if kind in ("integer", "number"):
            return self._number(schema, value, where)
        if kind == "string":
            return self._string(schema, value, where)
        if kind == "array":
            return self._array(schema, value, path)
        return self._object(schema, value, path)

    def _number(self, schema: dict[str, Any], value: Any, where: str) -> int | float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ToolArgumentError(f"{where} must be {_WHAT[schema['type']]}, not {_show(value)}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ToolArgumentError(f"{where} must be a finite number")
        number: int | float = value
        if schema["type"] == "integer" and isinstance(value, float):
            if not value.is_integer():
                raise ToolArgumentError(f"{where} must be a whole number, not {_show(value)}")
            number = int(value)
        elif schema["type"] == "number" and isinstance(value, int):
            if abs(value) > 2**1023:
                raise ToolArgumentError(f"{where} is far too large")
            number = float(value)
        if "minimum" in schema and number < schema["minimum"]:
            raise ToolArgumentError(
                f"{where} must be at least {_number_text(schema['minimum'])}, not {_show(value)}"
            )
        if "maximum" in schema and number > schema["maximum"]:
            raise ToolArgumentError(
                f"{where} must be at most {_number_text(schema['maximum'])}, not {_show(value)}"
            )
        return number

    def _string(self, schema: dict[str, Any], value: Any, where: str) -> str:
        if not isinstance(value, str):
            raise ToolArgumentError(
                f"{where} must be {'one of the names' if 'enum' in schema else 'text'}, not {_show(value)}"
            )
        if "enum" in schema and value not in schema["enum"]:
            names = schema["enum"]
            shown = ", ".join(names[:MAX_SHOWN]) + (", …" if len(names) > MAX_SHOWN else "")
            raise ToolArgumentError(f"{where} must be one of: {shown} (not {_show(value)})")
        if schema.get("contentEncoding") == "base64":
            try:
                base64.b64decode(value, validate=True)
            except (binascii.Error, ValueError):
                raise ToolArgumentError(f"{where} must be base64 text") from None
        if "maxLength" in schema and len(value) > schema["maxLength"]:
            raise ToolArgumentError(f"{where} is too long: at most {schema['maxLength']} characters")
        if "minLength" in schema and len(value) < schema["minLength"]:
            raise ToolArgumentError(f"{where} is too short: at least {schema['minLength']} characters")
        return value

    def _array(self, schema: dict[str, Any], value: Any, path: str) -> list[Any]:
        where = self.where(path)
        if not isinstance(value, list):
            raise ToolArgumentError(f"{where} must be a list, not {_show(value)}")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            raise ToolArgumentError(
                f"{where} has {len(value)} items, at most {schema['maxItems']} are allowed"
            )
        if "minItems" in schema and len(value) < schema["minItems"]:
            raise ToolArgumentError(f"{where} has {len(value)} items, it needs {schema['minItems']}")
        return [self.check(schema["items"], item, f"{path}[{index}]") for index, item in enumerate(value)]

    def _object(self, schema: dict[str, Any], value: Any, path: str) -> dict[str, Any]:
        where = self.where(path)
        if not isinstance(value, dict):
            raise ToolArgumentError(f"{where} must be an object, not {_show(value)}")
        properties: dict[str, Any] = schema.get("properties", {})
        unknown = sorted(name for name in value if name not in properties)
        if unknown:
            known = ", ".join(sorted(properties)[:MAX_SHOWN]) or "none"
            what = (
                f"unknown {self.label} {unknown[0]!r}" if not path else f"{where} has no field {unknown[0]!r}"
            )
            raise ToolArgumentError(f"{what} (expected: {known})"[:300])
        for name in schema.get("required", []):
            if name not in value:
                raise ToolArgumentError(
                    f"missing {self.label} {name!r}" if not path else f"{where} needs {name!r}"
                )
        return {
            name: self.check(properties[name], item, f"{path}.{name}" if path else name)
            for name, item in value.items()
        }


def check_schema(schema: Any) -> None:
    """Raise ValueError unless `schema` is within the subset above: an untrusted catalog's schema
    must not be able to crash or stall the validator."""
    nodes = [0]
    _check_node(schema, "parameters", 0, nodes)
    if schema.get("type") != "object":
        raise ValueError("parameters: the top level must be an object")


def _check_node(schema: Any, where: str, depth: int, nodes: list[int]) -> None:
    nodes[0] += 1
    if nodes[0] > MAX_SCHEMA_NODES or depth > MAX_DEPTH:
        raise ValueError(f"{where}: the schema is too big or too deep")
    if not isinstance(schema, dict) or schema.get("type") not in TYPES:
        raise ValueError(f"{where}: not a schema with a known type")
    kind = schema["type"]
    unknown = set(schema) - _KEYS[kind] - {"type", "description"}
    if unknown:
        raise ValueError(f"{where}: unexpected keywords {sorted(unknown)[:5]}")
    if not isinstance(schema.get("description", ""), str) or len(schema.get("description", "")) > 4000:
        raise ValueError(f"{where}: description must be text of at most 4000 characters")
    for key in ("minItems", "maxItems", "minLength", "maxLength"):
        if key in schema and not _whole(schema[key]):
            raise ValueError(f"{where}: {key} must be a whole number >= 0")
    for key in ("minimum", "maximum"):
        bound = schema.get(key, 0)
        if isinstance(bound, bool) or not isinstance(bound, (int, float)) or not math.isfinite(bound):
            raise ValueError(f"{where}: {key} must be a finite number")
    if "contentEncoding" in schema and schema["contentEncoding"] != "base64":
        raise ValueError(f"{where}: only base64 content is known")
    if "enum" in schema:
        names = schema["enum"]
        if not isinstance(names, list) or not names or len(names) > MAX_ENUM:
            raise ValueError(f"{where}: enum must list 1..{MAX_ENUM} names")
        if not all(isinstance(name, str) for name in names) or len(set(names)) != len(names):
            raise ValueError(f"{where}: enum names must be distinct texts")
    if kind == "array":
        _check_node(schema.get("items"), f"{where}.items", depth + 1, nodes)
    if kind == "object":
        properties = schema.get("properties", {})
        if not isinstance(properties, dict) or schema.get("additionalProperties") is not False:
            raise ValueError(f"{where}: an object needs properties and additionalProperties false")
        required = schema.get("required", [])
        if not isinstance(required, list) or not all(name in properties for name in required):
            raise ValueError(f"{where}: required must list some of its properties")
        if len(set(required)) != len(required):
            raise ValueError(f"{where}: required lists a property twice")
        for name, item in properties.items():
            if not isinstance(name, str) or not name or len(name) > 64:
                raise ValueError(f"{where}: property names are texts of 1..64 characters")
            _check_node(item, f"{where}.{name}", depth + 1, nodes)


def _whole(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def build_message(fixed: dict[str, Any], contributions: list[tuple[str, Any]]) -> dict[str, Any]:
    """The request/goal/message: the fixed fields, then each argument's value (a choice's fields or
    the model's value) placed at its field. Fixed fields win (configs where they would collide are
    refused at load; this is the second line)."""
    message = copy.deepcopy(fixed)
    for field, value in contributions:
        merge_into(message, placed(field, value))
    return message
