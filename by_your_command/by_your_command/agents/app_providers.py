"""Provider kinds by name: validate a config's `provider` section and build the session factory.

`openai`, `gpt_live` (OPENAI_API_KEY too), `gemini` and `offline` (no key). The API key is read
from the environment once, at start (a missing key is a config error, not a failure at the first
utterance), and handed to the provider object; it is never put in a message. A kind may accept
several variables: Gemini takes GOOGLE_API_KEY, else GEMINI_API_KEY (google-genai's own precedence,
so every program on the machine picks the same key); `provider.api_key_env` names the one variable
to read instead.
"""

from __future__ import annotations

import dataclasses
import logging
import types
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

from by_your_command.agents.app_config import ProviderChoice
from by_your_command.agents.config import AgentConfigError
from by_your_command.agents.provider import ProviderFactory

log = logging.getLogger(__name__)

# Header names that carry credentials: they come from the environment, never from a file.
_SECRET_HEADERS = frozenset({"authorization", "api-key", "x-api-key", "proxy-authorization", "cookie"})


@dataclass(frozen=True)
class BuiltProvider:
    factory: ProviderFactory
    settings: Mapping[str, Any]  # every setting with its default filled in (for --check)
    secret: str  # the key, so logging can redact it; "" for providers without one
    key_env: str = ""  # the environment variable it came from
    # Heavy local set-up done once before the agent starts listening. The offline engine's load
    # holds the GIL for seconds even in a thread: during a turn it would stall the event loop.
    warm_up: Callable[[], None] | None = None


@dataclass(frozen=True)
class ProviderKind:
    key_envs: tuple[str, ...]  # variables that may hold the key, the first set one wins; () = no key
    build: Callable[[Mapping[str, Any], str], BuiltProvider]  # (settings, key) → factory


def find_key(key_envs: tuple[str, ...], environ: Mapping[str, str]) -> tuple[str, str]:
    """(variable, key) of the first variable set (blank counts as unset); ("", "") when none is."""
    for name in key_envs:
        key = environ.get(name, "").strip()
        if key:
            return name, key
    return "", ""


def _not_set(key_envs: tuple[str, ...]) -> str:
    if len(key_envs) == 1:
        return f"{key_envs[0]} is not set"
    return f"neither {', '.join(key_envs[:-1])} nor {key_envs[-1]} is set"


def build_provider(choice: ProviderChoice, environ: Mapping[str, str]) -> BuiltProvider:
    """The factory for `choice`; AgentConfigError for an unknown kind, bad settings or a missing key."""
    kind = PROVIDER_KINDS.get(choice.type)
    if kind is None:
        raise AgentConfigError(
            [f"provider.type: must be one of {sorted(PROVIDER_KINDS)}, got {choice.type!r}"]
        )
    key_envs = (choice.api_key_env,) if choice.api_key_env else kind.key_envs
    key_env, key = find_key(key_envs, environ)
    ignored = [name for name in key_envs if name != key_env and environ.get(name, "").strip()]
    if key and ignored:
        log.warning(
            "%s is used for the %s key; %s is set too and ignored", key_env, choice.type, ", ".join(ignored)
        )
    problems = []
    built = None
    try:
        built = kind.build(choice.settings, key)
    except AgentConfigError as error:
        problems.extend(error.problems)
    if key_envs and not key:
        where = f"the {choice.type} API key comes from the environment, never from files"
        problems.append(f"{_not_set(key_envs)}: {where}")
    if problems:
        raise AgentConfigError(problems)
    assert built is not None
    return dataclasses.replace(built, key_env=key_env)


# --- openai and gemini -------------------------------------------------------------------------


def _cloud_settings(cls: Any, settings: Mapping[str, Any]) -> tuple[Any, dict[str, Any]]:
    """A cloud provider's config, and every setting for --check; its `extra_headers` may not carry
    credentials (they come from the environment)."""
    config = typed_settings(cls, settings, "provider")
    bad_headers = sorted(name for name, _ in config.extra_headers if name.lower() in _SECRET_HEADERS)
    if bad_headers:
        raise AgentConfigError(
            [f"provider.extra_headers.{bad_headers[0]}: credentials come from the environment, not files"]
        )
    values = dataclasses.asdict(config)
    values["extra_headers"] = dict(config.extra_headers)
    return config, values


# --- openai ------------------------------------------------------------------------------------


def _build_openai(settings: Mapping[str, Any], key: str) -> BuiltProvider:
    # Imported here: the openai SDK is only needed by agents that use it.
    from by_your_command.agents.providers.openai_realtime.provider import (
        OpenAIRealtimeConfig,
        OpenAIRealtimeProvider,
    )

    config, values = _cloud_settings(OpenAIRealtimeConfig, settings)

    def factory() -> OpenAIRealtimeProvider:
        return OpenAIRealtimeProvider(config, api_key=key)

    return BuiltProvider(factory, values, key)


# --- offline -----------------------------------------------------------------------------------


def _build_offline(settings: Mapping[str, Any], key: str) -> BuiltProvider:
    # Imported here: pocketsphinx is only needed by agents that use it.
    try:
        from by_your_command.agents.providers.local.config import OfflineConfig
        from by_your_command.agents.providers.local.engine import LocalEngine
        from by_your_command.agents.providers.local.provider import OfflineProvider
    except ImportError as missing:
        raise AgentConfigError([f"provider.type: offline needs {missing.name or missing}"]) from None

    config = typed_settings(OfflineConfig, settings, "provider")
    engine = LocalEngine(config)  # loaded by the first session, then shared by every later one

    def factory() -> OfflineProvider:
        return OfflineProvider(config, engine)

    values = dataclasses.asdict(config)
    values["acknowledgements"] = dict(config.acknowledgements)
    return BuiltProvider(factory, values, "", warm_up=engine.load)


# --- gemini ------------------------------------------------------------------------------------


def _build_gemini(settings: Mapping[str, Any], key: str) -> BuiltProvider:
    # Imported here: google-genai is only needed by agents that use it.
    from by_your_command.agents.providers.gemini_live.provider import GeminiLiveConfig, GeminiLiveProvider
    from by_your_command.agents.providers.gemini_live.resumption import ResumptionHandles

    config, values = _cloud_settings(GeminiLiveConfig, settings)
    handles = ResumptionHandles()  # one per agent: every session of this agent resumes the last one

    def factory() -> GeminiLiveProvider:
        return GeminiLiveProvider(config, api_key=key, resumption=handles)

    return BuiltProvider(factory, values, key)


# --- gpt_live ----------------------------------------------------------------------------------


def _build_gpt_live(settings: Mapping[str, Any], key: str) -> BuiltProvider:
    # Imported here: the openai SDK is only needed by agents that use it.
    from by_your_command.agents.providers.gpt_live.config import GptLiveConfig
    from by_your_command.agents.providers.gpt_live.provider import GptLiveProvider

    config, values = _cloud_settings(GptLiveConfig, settings)

    def factory() -> GptLiveProvider:
        return GptLiveProvider(config, api_key=key)

    return BuiltProvider(factory, values, key)


PROVIDER_KINDS: dict[str, ProviderKind] = {
    "openai": ProviderKind(("OPENAI_API_KEY",), _build_openai),
    "gpt_live": ProviderKind(("OPENAI_API_KEY",), _build_gpt_live),
    # google-genai's order: GOOGLE_API_KEY wins when both are set (the provider logs which is used)
    "gemini": ProviderKind(("GOOGLE_API_KEY", "GEMINI_API_KEY"), _build_gemini),
    "offline": ProviderKind((), _build_offline),
}


# --- typed settings ----------------------------------------------------------------------------


def typed_settings(cls: Any, settings: Mapping[str, Any], prefix: str) -> Any:
    """`cls(**settings)` for a frozen dataclass of simple fields, each value checked against its
    type hint first (str, int, float, bool, Literal, optional, and a str→str mapping for a tuple of
    pairs). Every problem names its key; all of them are raised together."""
    hints = get_type_hints(cls)
    names = [item.name for item in dataclasses.fields(cls)]
    problems = [
        f"{prefix}.{key}: unknown key (known: {', '.join(sorted(names))})"
        for key in settings
        if key not in names
    ]
    values = {}
    for name in names:
        if name in settings:
            try:
                values[name] = _typed(hints[name], settings[name])
            except ValueError as error:
                problems.append(f"{prefix}.{name}: {error}")
    if not problems:
        try:
            return cls(**values)
        except (TypeError, ValueError) as error:
            problems.append(f"{prefix}: {error}")
    raise AgentConfigError(problems)


def _typed(hint: Any, value: Any) -> Any:
    origin = get_origin(hint)
    if origin is Literal:
        allowed = list(get_args(hint))
        if value not in allowed or type(value) is not type(allowed[0]):
            raise ValueError(f"must be one of {allowed}, got {value!r}")
        return value
    if origin in (Union, types.UnionType):
        options = [arg for arg in get_args(hint) if arg is not type(None)]
        if value is None and len(options) < len(get_args(hint)):
            return None
        return _typed(options[0], value)
    if hint == tuple[tuple[str, str], ...]:
        if not isinstance(value, Mapping) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in value.items()
        ):
            raise ValueError("must be a mapping of strings to strings")
        return tuple(value.items())
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
            raise ValueError(f"must be a number, got {value!r}")
        return float(value)
    if hint in (int, str, bool):
        if type(value) is not hint:
            raise ValueError(f"must be {hint.__name__}, got {type(value).__name__} {value!r}")
        return value
    raise ValueError(f"cannot be set from a config file (type {hint})")
