"""Wire rules of the GPT-Live emulator, taken from the official SDK's own types (openai.types.live).

Client events are checked against the SDK's param TypedDicts (`ClientEventParam`): the event is
picked by its `type`, then every key is walked: unknown keys, missing `Required` keys, wrong JSON
types and values outside a `Literal` are refused with the error the SDK's `ErrorEvent` describes
(codes `unknown_parameter`, `missing_required_parameter`, `invalid_type`, `invalid_value`; the
message wording is the Realtime API's, the GPT-Live one is not documented). Server events are the
SDK's pydantic models, serialised the way the SDK itself serialises models (`to_json`, API names,
only the fields set), so the SDK parses them back into the same types.
"""

from __future__ import annotations

import collections.abc
import functools
import types
import typing
from typing import Any, Literal, Union

import typing_extensions
from openai.types.live import Error, ErrorEvent
from openai.types.live.client_event_param import ClientEventParam
from pydantic import BaseModel

from by_your_command.emulators.openai_wire import ClientEventError, JsonObject, new_id

__all__ = [
    "EVENT_PARAMS",
    "ClientEventError",
    "JsonObject",
    "error_event",
    "estimated_tokens",
    "new_id",
    "serialise",
    "validate_client_event",
]

_REQUIRED = (typing_extensions.Required, getattr(typing, "Required", typing_extensions.Required))
_NOT_REQUIRED = (typing_extensions.NotRequired, getattr(typing, "NotRequired", typing_extensions.NotRequired))
_LIST_ORIGINS = (list, collections.abc.Iterable, collections.abc.Sequence)
_MAPPING_ORIGINS = (dict, collections.abc.Mapping)
_KIND_NAMES = {str: "a string", int: "an integer", float: "a number", bool: "a boolean"}


@functools.cache
def _hints(typed_dict: type) -> dict[str, Any]:
    return typing.get_type_hints(typed_dict, include_extras=True)


def _unwrap(hint: Any) -> Any:
    """The type under Required / NotRequired / Annotated."""
    while typing.get_origin(hint) in (*_REQUIRED, *_NOT_REQUIRED, typing_extensions.Annotated):
        hint = typing.get_args(hint)[0]
    return hint


def _required_keys(typed_dict: type) -> set[str]:
    hints = _hints(typed_dict)
    marked = {key for key, hint in hints.items() if typing.get_origin(hint) in _REQUIRED}
    total = set(getattr(typed_dict, "__required_keys__", ()))
    return marked | {key for key in total if typing.get_origin(hints.get(key)) not in _NOT_REQUIRED}


def _literal_key(members: list[Any]) -> str | None:
    """A key every TypedDict member declares as a Literal (`type`, `role`): the union's tag."""
    if not members or not all(typing_extensions.is_typeddict(member) for member in members):
        return None
    common = set.intersection(*(set(_hints(member)) for member in members))
    for key in sorted(common, key=lambda name: name != "type"):
        hints = [_unwrap(_hints(member)[key]) for member in members]
        if not all(typing.get_origin(hint) is Literal for hint in hints):
            continue
        values = [value for hint in hints for value in typing.get_args(hint)]
        if len(values) == len(set(values)):  # each value names one member
            return key
    return None


def _join(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


def _json_kind(value: object) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "an array"
    return "an object" if isinstance(value, dict) else "null"


def _wrong_type(path: str, expected: str, value: object) -> ClientEventError:
    return ClientEventError(
        "invalid_type",
        f"Invalid type for '{path}': expected {expected}, but got {_json_kind(value)}.",
        path,
    )


def check_value(hint: Any, value: object, path: str) -> None:
    """Refuse `value` unless it has the shape `hint` (an SDK param type) describes."""
    hint = _unwrap(hint)
    origin = typing.get_origin(hint)
    if hint is Any or hint is object:
        return
    if origin is Union or origin is types.UnionType:
        _check_union(list(typing.get_args(hint)), value, path)
    elif origin is Literal:
        allowed = typing.get_args(hint)
        if not any(value == option and type(value) is type(option) for option in allowed):
            shown = repr(value)[:64]
            options = ", ".join(repr(option) for option in allowed)
            raise ClientEventError(
                "invalid_value",
                f"Invalid value for '{path}': {shown}. Supported values are: {options}.",
                path,
            )
    elif typing_extensions.is_typeddict(hint):
        _check_typed_dict(hint, value, path)
    elif hint is type(None):
        if value is not None:
            raise _wrong_type(path, "null", value)
    elif hint in _KIND_NAMES:
        _check_scalar(hint, value, path)
    elif origin in _MAPPING_ORIGINS:
        if not isinstance(value, dict):
            raise _wrong_type(path, "an object", value)
        value_hint = typing.get_args(hint)[1] if len(typing.get_args(hint)) == 2 else Any
        for key, item in value.items():
            check_value(value_hint, item, _join(path, key))
    elif origin in _LIST_ORIGINS or getattr(origin, "__name__", "") == "SequenceNotStr":
        if not isinstance(value, list):
            raise _wrong_type(path, "an array", value)
        item_hint = (typing.get_args(hint) or (Any,))[0]
        for index, item in enumerate(value):
            check_value(item_hint, item, _join(path, index))
    # Anything else (files, dates: nothing a Live event carries) is accepted as is.


def _check_scalar(kind: type, value: object, path: str) -> None:
    fits = (
        isinstance(value, bool)
        if kind is bool
        else isinstance(value, (int, float)) and not isinstance(value, bool)
        if kind is float
        else isinstance(value, kind) and not isinstance(value, bool)
    )
    if not fits:
        raise _wrong_type(path, _KIND_NAMES[kind], value)


def _check_typed_dict(typed_dict: type, value: object, path: str) -> None:
    if not isinstance(value, dict):
        raise _wrong_type(path, "an object", value)
    hints = _hints(typed_dict)
    for key in value:
        if key not in hints:
            where = _join(path, key)
            raise ClientEventError("unknown_parameter", f"Unknown parameter: '{where}'.", where)
    for key in sorted(_required_keys(typed_dict)):
        if key not in value:
            where = _join(path, key)
            raise ClientEventError(
                "missing_required_parameter", f"Missing required parameter: '{where}'.", where
            )
    for key, item in value.items():
        check_value(hints[key], item, _join(path, key))


def _check_union(members: list[Any], value: object, path: str) -> None:
    if value is None:
        if type(None) in members:
            return
        raise _wrong_type(path, "a value", value)
    members = [member for member in members if member is not type(None)]
    tag = _literal_key([_unwrap(member) for member in members])
    if tag is not None and isinstance(value, dict):
        where = _join(path, tag)
        if tag not in value:
            if all(tag in _required_keys(_unwrap(member)) for member in members):
                raise ClientEventError(
                    "missing_required_parameter", f"Missing required parameter: '{where}'.", where
                )
            tag = None  # an optional tag: the members are tried in turn below
    if tag is not None and isinstance(value, dict):
        where = _join(path, tag)
        for member in members:
            if value[tag] in typing.get_args(_unwrap(_hints(_unwrap(member))[tag])):
                check_value(member, value, path)
                return
        options = ", ".join(
            repr(option)
            for member in members
            for option in typing.get_args(_unwrap(_hints(_unwrap(member))[tag]))
        )
        raise ClientEventError(
            "invalid_value",
            f"Invalid value for '{where}': {repr(value[tag])[:64]}. Supported values are: {options}.",
            where,
        )
    errors: list[ClientEventError] = []
    for member in members:
        try:
            check_value(member, value, path)
            return
        except ClientEventError as error:
            errors.append(error)
    # The most specific complaint (the deepest parameter) says best what went wrong.
    raise max(errors, key=lambda error: len(error.param or ""))


def _event_params() -> dict[str, type]:
    params: dict[str, type] = {}
    for member in typing.get_args(ClientEventParam):
        (kind,) = typing.get_args(_unwrap(_hints(member)["type"]))
        params[kind] = member
    return params


EVENT_PARAMS: dict[str, type] = _event_params()  # every client event type the SDK can send


def validate_client_event(event: JsonObject) -> None:
    """Refuse an event the SDK would not send (unknown type, unknown key, wrong shape)."""
    kind = event.get("type")
    params = EVENT_PARAMS.get(kind) if isinstance(kind, str) else None
    if params is None:
        raise ClientEventError(
            "invalid_value", f"Invalid value: '{str(kind)[:64]}'. Unknown event type.", "type"
        )
    check_value(params, event, "")


def estimated_tokens(text: str) -> int:
    """About four characters a token: enough to hold the documented token limits."""
    return (len(text) + 3) // 4


def error_event(
    code: str,
    message: str,
    param: str | None = None,
    client_event_id: str | None = None,
    kind: str = "invalid_request_error",
) -> ErrorEvent:
    """The SDK's `ErrorEvent`; the client's event_id is echoed in both places the SDK has for it."""
    error = Error(code=code, message=message, type=kind, param=param)
    event = ErrorEvent(type="error", event_id=new_id("event"), error=error)
    if client_event_id is not None:
        error.client_event_id = client_event_id
        event.client_event_id = client_event_id
    return event


def serialise(event: BaseModel) -> str:
    """JSON text of an SDK model, as the SDK writes models: API names, only the fields set."""
    to_json = getattr(event, "to_json", None)
    if to_json is None:
        return event.model_dump_json(by_alias=True, exclude_unset=True)
    return str(to_json(indent=None))
