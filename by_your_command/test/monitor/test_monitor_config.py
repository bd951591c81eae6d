"""config/monitor.yaml: strict parsing, and the shipped file prices the providers we ship."""

from __future__ import annotations

from pathlib import Path

import pytest
from live_bridge import CONFIG_DIR

from by_your_command.agents.providers.gemini_live.provider import GeminiLiveProvider
from by_your_command.agents.providers.gpt_live.provider import GptLiveProvider
from by_your_command.agents.providers.local.provider import OfflineProvider
from by_your_command.agents.providers.openai_realtime.provider import OpenAIRealtimeProvider
from by_your_command.monitor.config import MonitorConfigError, load_monitor_config, parse_monitor_config

pytestmark = pytest.mark.unit


def test_the_shipped_file_prices_every_provider_by_its_name() -> None:
    config = load_monitor_config(CONFIG_DIR / "monitor.yaml")
    names = {OpenAIRealtimeProvider.name, GeminiLiveProvider.name, GptLiveProvider.name, OfflineProvider.name}
    assert set(config.prices) == names
    assert config.prices["openai_realtime"].output_audio > 0 and config.prices["offline"].output_audio == 0
    assert config.prices["gpt_live"].session_minute > 0  # billed per second of open session
    assert config.for_page()["page"]["camera_interval_ms"] == config.page.camera_interval_ms


@pytest.mark.parametrize(
    ("data", "why"),
    [
        (
            {"prices": {"openai_realtime": {"output_adio": 1.0}}},
            r"prices.openai_realtime: unknown key\(s\) \['output_adio'\]",
        ),
        ({"prices": {"openai_realtime": {"output_audio": -1}}}, "prices.openai_realtime.output_audio"),
        ({"prices": {"openai_realtime": {"output_audio": "cheap"}}}, "output_audio"),
        ({"prices": {"openai_realtime": 3}}, "expected a mapping"),
        ({"page": {"transcript_lines": 0}}, "page.transcript_lines"),
        ({"pages": {}}, "unknown key"),
        ({"currency": ""}, "currency"),
        ([1, 2], "mapping at the top level"),
    ],
)
def test_mistakes_are_startup_errors_naming_the_key(data: object, why: str) -> None:
    with pytest.raises(MonitorConfigError, match=why):
        parse_monitor_config(data)


def test_an_unreadable_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(MonitorConfigError, match="cannot read monitor config"):
        load_monitor_config(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("prices: [unclosed")
    with pytest.raises(MonitorConfigError, match="not valid YAML"):
        load_monitor_config(bad)
