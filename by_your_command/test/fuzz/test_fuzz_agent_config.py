"""Hostile agent config files, `--set` assignments and environment: an AppConfig or AgentConfigError.

`load_app_config` is what `byc agent` runs first; whatever the file holds (wrong types, NaN,
huge numbers, credentials in URLs, YAML bombs, deep nesting, bytes that are not UTF-8), the
answer is a valid configuration or one AgentConfigError listing the problems, in bounded time.
"""

from __future__ import annotations

import atexit
import dataclasses
import shutil
import tempfile
from pathlib import Path
from typing import Any, get_type_hints

import pytest
from fuzzing import ODD_TEXT, TALLY, fuzz_settings
from hypothesis import given
from hypothesis import strategies as st
from yaml_fuzz import PLAIN, documents, mapping_bomb, sometimes_wrong

from by_your_command.agents.app_config import (
    MAX_CONFIG_VALUES,
    AppConfig,
    describe,
    load_app_config,
)
from by_your_command.agents.config import AgentConfig, AgentConfigError, Topics

pytestmark = [pytest.mark.unit, pytest.mark.timeout(600)]

WORKDIR = Path(tempfile.mkdtemp(prefix="byc_fuzz_agent_config_"))
atexit.register(shutil.rmtree, WORKDIR, ignore_errors=True)


def plausible(hint: Any) -> st.SearchStrategy[Any]:
    if isinstance(hint, type) and issubclass(hint, str) and hasattr(hint, "__members__"):  # str enums
        return st.sampled_from([member.value for member in hint])  # type: ignore[attr-defined]
    if hint is float:
        return st.floats(-1e6, 1e6) | st.sampled_from([0.0, 1e308, float("inf")])
    if hint is int:
        return st.integers(-10, 10_000) | st.just(2**64)
    if hint is str:
        return ODD_TEXT
    if hint is Topics:
        return st.fixed_dictionaries({}, optional={f.name: ODD_TEXT for f in dataclasses.fields(Topics)})
    return st.dictionaries(
        st.sampled_from(["type", "api_key_env", "model", "voice", "api_key", "url"]) | ODD_TEXT,
        PLAIN,
        max_size=4,
    )


HINTS = get_type_hints(AgentConfig)
AGENT_FIELDS = {f.name: sometimes_wrong(plausible(HINTS[f.name])) for f in dataclasses.fields(AgentConfig)}
URLS = (
    st.sampled_from(
        [
            "ws://127.0.0.1:9090",
            "wss://robot.local:443/",
            "ws://user:pw@host:1",
            "ws://h/?token=abc",
            "ws://[::1",
            "ws://h:99999",
            "ws://h:-1",
            "http://h:1",
            "ws://",
            "ws://\u0430\u0440\u0440\u04cf\u0435.com",
            "ws://h:1/" + "a" * 10_000,
        ]
    )
    | ODD_TEXT
)
BRIDGE = st.fixed_dictionaries(
    {}, optional={"url": sometimes_wrong(URLS), "token_env": sometimes_wrong(ODD_TEXT), "token": PLAIN}
)
LAYOUT = st.fixed_dictionaries({}, optional={**AGENT_FIELDS, "bridge": sometimes_wrong(BRIDGE)})
ASSIGNMENTS = st.lists(
    st.tuples(
        st.sampled_from(
            ["role", "provider.type", "bridge.url", "topics.camera", "a.b.c", "", "x.", "max_session_s"]
        )
        | ODD_TEXT,
        st.sampled_from(["=", "", "=="]),
        PLAIN.map(str) | st.sampled_from(["[" * 2000, "&a [*a]", "{", "!!python/name:os.system", "1e400"]),
    ).map("".join),
    max_size=3,
)
ENVIRON = st.fixed_dictionaries({}, optional={"BYC_BRIDGE_URL": URLS, "BYC_BRIDGE_TOKEN": ODD_TEXT})


@fuzz_settings(short=150, long=3_000)
@given(documents(LAYOUT), ASSIGNMENTS, ENVIRON)
def test_any_agent_config_is_valid_or_one_agent_config_error(
    content: str | bytes, assignments: list[str], environ: dict[str, str]
) -> None:
    path = WORKDIR / "agent.yaml"
    path.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8", "surrogatepass"))
    with TALLY.input("agents.load_app_config"):
        try:
            app = load_app_config(str(path), assignments, environ)
        except AgentConfigError as error:
            assert error.problems and all(isinstance(p, str) and p for p in error.problems)
            return
        assert isinstance(app, AppConfig) and isinstance(app.agent, AgentConfig)
        assert app.bridge.url.startswith(("ws://", "wss://"))
        described = describe(app, app.provider.settings, app.provider.api_key_env, environ)
        assert "token" not in described["bridge"] or described["bridge"]["token"] is None


def test_a_yaml_alias_bomb_is_refused_before_it_is_copied() -> None:
    """Regression: 740 bytes of anchors took 83 s (10^7 dict copies) before any error; this one
    (10^6 copies) takes seconds when the test fails."""
    path = WORKDIR / "bomb.yaml"
    path.write_text(mapping_bomb(7, 10, "provider"))
    with pytest.raises(AgentConfigError, match=f"more than {MAX_CONFIG_VALUES} values"):
        load_app_config(str(path))


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("a: " + "[" * 5000 + "]" * 5000, "nested deeper than 64 levels"),
        ("- " * 2000 + "x", "nested too deeply"),
        ("# " + "x" * (1 << 20), "larger than"),
    ],
    ids=["deep-flow", "deep-block", "huge"],
)
def test_deep_or_huge_agent_configs_are_config_errors(content: str, message: str) -> None:
    """Regression: a deeply nested file escaped as RecursionError (after 3 s of PyYAML scanning)."""
    path = WORKDIR / "odd.yaml"
    path.write_text(content)
    with pytest.raises(AgentConfigError, match=message):
        load_app_config(str(path))


def test_a_deeply_nested_set_value_is_taken_as_text() -> None:
    """Regression: `--set x=[[[[...` escaped as RecursionError from the YAML parser."""
    path = WORKDIR / "ok.yaml"
    path.write_text("agent_id: a\n")
    with pytest.raises(AgentConfigError, match="x: unknown key"):
        load_app_config(str(path), ["x=" + "[" * 5000])
