"""Shared pytest setup: markers policy and per-test ROS isolation."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

LIVE_KEYS = ("OPENAI_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    in_ci = os.environ.get("CI", "").lower() in ("1", "true", "yes")
    have_key = any(os.environ.get(key) for key in LIVE_KEYS)
    reason = (
        "live API tests never run in CI" if in_ci else "live API tests need an API key in the environment"
    )
    for item in items:
        if "live" in item.keywords and (in_ci or not have_key):
            item.add_marker(pytest.mark.skip(reason=reason))


@pytest.fixture
def ros_namespace() -> str:
    """A namespace no other test uses, so graphs in one ROS domain never cross-talk."""
    return f"/t_{uuid.uuid4().hex[:10]}"


@pytest.fixture(scope="session", autouse=True)
def private_state_home(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Nodes keep state under $XDG_STATE_HOME (the echo path they learned, recordings): the
    tests' nodes keep theirs in a directory of this run, never in the user's home."""
    before = os.environ.get("XDG_STATE_HOME")
    state = tmp_path_factory.mktemp("state")
    os.environ["XDG_STATE_HOME"] = str(state)
    yield state
    if before is None:
        del os.environ["XDG_STATE_HOME"]
    else:
        os.environ["XDG_STATE_HOME"] = before
