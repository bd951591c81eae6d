"""Fixtures: config files whose values the graph tests choose (graph_files.py)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml
from graph.graph_files import AGENT_CONFIGS, write_config_prefix


@pytest.fixture
def config_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A prefix whose config/ holds the test's audio_io.yaml and vad.yaml, searched first."""
    config = write_config_prefix(tmp_path / "prefix")
    monkeypatch.setenv(
        "AMENT_PREFIX_PATH", f"{tmp_path / 'prefix'}{os.pathsep}{os.environ.get('AMENT_PREFIX_PATH', '')}"
    )
    return config


@pytest.fixture
def agent_dir(tmp_path: Path) -> Path:
    directory = tmp_path / "agents"
    directory.mkdir()
    for name, data in AGENT_CONFIGS.items():
        (directory / name).write_text(yaml.safe_dump(data))
    return directory
