"""An agent process's config file: the runtime's `AgentConfig` plus what only the process needs.

The file is the AgentConfig mapping (config.py) with two additions the process takes out first:
`bridge` (where ros_ai_bridge is, and which environment variable holds its token) and, inside
`provider`, `type` (which vendor) and `api_key_env` (which environment variable holds the key).
Values come from the file, then BYC_BRIDGE_URL, then `--set key=value` (last wins). Every value is
untrusted: problems are collected and raised together as one AgentConfigError. Secrets never live
here: a key, token or credential-bearing URL in the file is refused.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import yaml

from by_your_command.agents.config import AgentConfig, AgentConfigError, EchoMode, parse_agent_config
from by_your_command.config_files.locate import ConfigFileNotFound, find_config_file
from by_your_command.config_files.located_yaml import BoundedSafeLoader

DEFAULT_BRIDGE_URL = "ws://127.0.0.1:9090"
BRIDGE_URL_ENV = "BYC_BRIDGE_URL"
BRIDGE_TOKEN_ENV = "BYC_BRIDGE_TOKEN"
DEFAULT_PROVIDER = "openai"
FULL_DUPLEX = frozenset({"gpt_live"})  # providers that take the mic while the robot talks
TOKEN_HINT = "the variable named by bridge.token_env"
MAX_CONFIG_BYTES = 1 << 20  # config files are a few KB
MAX_CONFIG_VALUES = 100_000  # counted with YAML aliases expanded; a real file has a few hundred


@dataclass(frozen=True)
class BridgeSettings:
    url: str = DEFAULT_BRIDGE_URL
    token_env: str = BRIDGE_TOKEN_ENV  # the token itself is only ever read from the environment


@dataclass(frozen=True)
class ProviderChoice:
    type: str  # a name in app_providers.PROVIDER_KINDS
    api_key_env: str  # "" = the kind's default variable
    settings: Mapping[str, Any]  # the rest of the `provider` section, validated by the kind


@dataclass(frozen=True)
class AppConfig:
    agent: AgentConfig
    provider: ProviderChoice
    bridge: BridgeSettings
    source: str  # the file it came from, for messages


def locate_config(name: str) -> Path:
    """An existing path as given; a bare file name (`agent_openai.yaml`) is searched like every
    config file (ROS prefixes, the source tree, the installed package)."""
    path = Path(name).expanduser()
    if path.is_file() or "/" in name:
        return path
    try:
        return find_config_file(name)
    except ConfigFileNotFound as missing:
        raise AgentConfigError([str(missing).replace("\n", " ")], name) from None


def read_config_file(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as file:
            raw = file.read(MAX_CONFIG_BYTES + 1)
        if len(raw) > MAX_CONFIG_BYTES:
            raise AgentConfigError([f"larger than {MAX_CONFIG_BYTES} bytes: not a config file"], str(path))
        data = yaml.load(raw.decode("utf-8"), Loader=BoundedSafeLoader)  # noqa: S506 - a SafeLoader
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        raise AgentConfigError([f"cannot read: {' '.join(str(error).split())}"], str(path)) from None
    except RecursionError:  # PyYAML composes recursively: "[[[[...]]]]" a few hundred deep
        raise AgentConfigError(["cannot read: nested too deeply"], str(path)) from None
    if _more_values_than(data, MAX_CONFIG_VALUES):
        # Ten anchors each naming the previous one ten times are 10^10 values once copied.
        raise AgentConfigError(
            [f"more than {MAX_CONFIG_VALUES} values once YAML aliases are expanded"], str(path)
        )
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise AgentConfigError([f"the top level must be a mapping, got {type(data).__name__}"], str(path))
    return data


def apply_overrides(data: Mapping[str, Any], assignments: Sequence[str], source: str) -> dict[str, Any]:
    """`--set a.b=value` assignments; values are YAML scalars (`--set min_barge_in_ms=300` is an int)."""
    result = _copy(data)
    problems = []
    for assignment in assignments:
        key, equals, text = assignment.partition("=")
        path = key.strip().split(".")
        if not equals or not all(path):
            problems.append(f"--set {assignment!r}: expected key=value (nested keys with dots)")
            continue
        try:
            value = yaml.load(text, Loader=BoundedSafeLoader) if text.strip() else ""  # noqa: S506
        except (yaml.YAMLError, RecursionError):
            value = text  # not YAML: take it as the string typed
        target = result
        for part in path[:-1]:
            inner = target.setdefault(part, {})
            if not isinstance(inner, dict):
                problems.append(f"--set {key}: {part} is not a mapping")
                break
            target = inner
        else:
            target[path[-1]] = value
    if problems:
        raise AgentConfigError(problems, source)
    return result


def apply_environment(data: Mapping[str, Any], environ: Mapping[str, str]) -> dict[str, Any]:
    """BYC_BRIDGE_URL, when set, points the agent at another bridge without editing the file."""
    result = _copy(data)
    url = environ.get(BRIDGE_URL_ENV, "").strip()
    if url:
        bridge = result.get("bridge")
        result["bridge"] = {**(bridge if isinstance(bridge, dict) else {}), "url": url}
    return result


def parse_app_config(data: Mapping[str, Any], source: str) -> AppConfig:
    problems: list[str] = []
    rest = dict(data)
    bridge = _bridge(rest.pop("bridge", {}), problems)
    provider_section = rest.get("provider", {})
    choice = None
    if isinstance(provider_section, Mapping):
        settings = dict(provider_section)
        kind = settings.pop("type", DEFAULT_PROVIDER)
        key_env = settings.pop("api_key_env", "")
        if not isinstance(kind, str) or not kind:
            problems.append(f"provider.type: must be a provider name, got {kind!r}")
        if not isinstance(key_env, str) or not _is_env_name(key_env, allow_empty=True):
            problems.append(f"provider.api_key_env: must be an environment variable name, got {key_env!r}")
        rest["provider"] = settings
        choice = ProviderChoice(str(kind), str(key_env), settings)
    try:
        agent = parse_agent_config(rest, source)
    except AgentConfigError as error:
        problems.extend(error.problems)
    else:
        if choice is not None and choice.type in FULL_DUPLEX and agent.echo_mode is EchoMode.GATE:
            problems.append(
                f"echo_mode: {choice.type} is full duplex (the model hears the user over its own voice "
                "and decides itself when to stop), so the microphone must stay open while the robot "
                "talks: use aec (echo cancelled on the robot) or external (echo-free mic), not gate"
            )
    if problems:
        raise AgentConfigError(problems, source)
    assert choice is not None and bridge is not None  # a bad provider section is a problem above
    return AppConfig(agent, choice, bridge, source)


def load_app_config(
    name: str, assignments: Sequence[str] = (), environ: Mapping[str, str] | None = None
) -> AppConfig:
    """The config file `name` (a path, or a file name in the config directories) with the
    environment and `--set` assignments applied, validated. Raises AgentConfigError."""
    path = locate_config(name)
    data = read_config_file(path)
    data = apply_environment(data, {} if environ is None else environ)
    data = apply_overrides(data, assignments, str(path))
    return parse_app_config(data, str(path))


def describe(
    app: AppConfig, provider_settings: Mapping[str, Any], key_env: str, environ: Mapping[str, str]
) -> dict[str, Any]:
    """The effective configuration as plain data, for `--check`: names of secrets, never values."""
    agent: dict[str, Any] = _plain(dataclasses.asdict(app.agent))
    agent["provider"] = {
        "type": app.provider.type,
        **({"api_key_env": f"{key_env} ({'set' if environ.get(key_env) else 'NOT SET'})"} if key_env else {}),
        **_plain(dict(provider_settings)),
    }
    token_set = "set" if environ.get(app.bridge.token_env) else "not set: no token sent"
    agent["bridge"] = {"url": app.bridge.url, "token_env": f"{app.bridge.token_env} ({token_set})"}
    return agent


# --- helpers -----------------------------------------------------------------------------------


def _bridge(section: Any, problems: list[str]) -> BridgeSettings | None:
    if not isinstance(section, Mapping):
        problems.append(f"bridge: must be a mapping, got {type(section).__name__}")
        return None
    known = {item.name for item in dataclasses.fields(BridgeSettings)}
    for key in section:
        if str(key).lower() in ("token", "password", "secret"):
            problems.append(
                f"bridge.{key}: the token comes from the environment (bridge.token_env), not files"
            )
        elif key not in known:
            problems.append(f"bridge.{key}: unknown key (known: {', '.join(sorted(known))})")
    url = section.get("url", DEFAULT_BRIDGE_URL)
    token_env = section.get("token_env", BRIDGE_TOKEN_ENV)
    if not isinstance(url, str):
        problems.append(f"bridge.url: must be str, got {type(url).__name__} {url!r}")
    else:
        problems.extend(_url_problems(url))
    if not isinstance(token_env, str) or not _is_env_name(token_env):
        problems.append(f"bridge.token_env: must be an environment variable name, got {token_env!r}")
    if problems:
        return None
    return BridgeSettings(url, token_env)


def _url_problems(url: str) -> list[str]:
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018 - raises ValueError for a port that is not a number
    except ValueError as error:
        return [f"bridge.url: not a URL ({error})"]
    if parts.scheme not in ("ws", "wss") or not parts.hostname:
        return [f"bridge.url: must be ws://host:port or wss://host:port, got {url[:80]!r}"]
    if parts.username or parts.password or "token" in parse_qs(parts.query):
        return [
            "bridge.url: must not carry credentials; the token comes from the environment (bridge.token_env)"
        ]
    return []


def _is_env_name(name: str, allow_empty: bool = False) -> bool:
    if not name:
        return allow_empty
    return name.replace("_", "a").isalnum() and name.isascii() and not name[0].isdigit()


def _more_values_than(data: Any, limit: int) -> bool:
    """Counts values as the copies below will see them (an alias counts each time it is used)."""
    stack, count = [data], 0
    while stack:
        item = stack.pop()
        count += 1
        if count > limit:
            return True
        if isinstance(item, Mapping):
            stack.extend(item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend(item)
    return False


def _copy(data: Mapping[str, Any]) -> dict[str, Any]:
    return {key: _copy(value) if isinstance(value, Mapping) else value for key, value in data.items()}


def _plain(value: Any) -> Any:
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, Mapping):
        return {str(key): _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    return value
