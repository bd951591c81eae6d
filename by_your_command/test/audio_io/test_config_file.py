"""config/audio_io.yaml names only real parameters and repeats the dataclass defaults."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from by_your_command.audio.devices import CaptureConfig
from by_your_command.audio.echo import EchoConfig
from by_your_command.audio.player import PlayerConfig

CONFIG = Path(__file__).resolve().parents[2] / "config" / "audio_io.yaml"


@pytest.mark.unit
@pytest.mark.parametrize(
    ("node", "config_type"),
    [
        ("audio_capture", CaptureConfig),
        ("echo_suppressor", EchoConfig),
        ("simple_audio_player", PlayerConfig),
    ],
)
def test_config_file_matches_the_defaults(node: str, config_type: type) -> None:
    params = yaml.safe_load(CONFIG.read_text())[f"/**/{node}"]["ros__parameters"]
    defaults = {f.name: f.default for f in dataclasses.fields(config_type)}
    assert set(params) <= set(defaults), f"unknown parameters: {set(params) - set(defaults)}"
    for name, value in params.items():
        assert value == defaults[name], f"{node}.{name}: file says {value!r}, default is {defaults[name]!r}"
