"""Config files the graph tests control: an overlay prefix searched before the shipped config/ (as a
ROS workspace overlay would be), and agent configs (their real ones are written by the agent work)."""

from __future__ import annotations

from pathlib import Path

import yaml

from by_your_command.config_files.locate import find_config_file

# Distinctive values: seeing them in a node's parameters proves they came from the config files.
VAD_SECTION = {"threshold": 0.61, "min_silence_duration_ms": 300, "wake_phrases": ["hey robot"]}
CLAP_SECTION = {"sample_rate": 16000, "enabled": False}  # fields every clap detector version has
PLAYER_SECTION = {"sample_rate": 22050, "block_ms": 20}
AGENT_CONFIGS = {
    "agent_openai.yaml": {"agent_id": "talker", "provider": {"model": "file-model", "voice": "alloy"}},
    "agent_openai_tool.yaml": {"agent_id": "tool", "provider": {"model": "file-model", "voice": "alloy"}},
    "agent_openai_command.yaml": {"agent_id": "commander", "role": "command", "provider": {"model": "m2"}},
    "agent_gemini.yaml": {"agent_id": "gemini", "provider": {"model": "g-live"}},
    "agent_gemini_tool.yaml": {"agent_id": "gemini_tool", "provider": {"model": "g-live"}},
    "agent_gemini_command.yaml": {"agent_id": "gemini_cmd", "role": "command"},
    "agent_gpt_live.yaml": {"agent_id": "live", "provider": {"type": "gpt_live", "model": "live-model"}},
    "agent_offline.yaml": {"agent_id": "offline", "provider": {"grammar": "commands"}},
}


def write_config_prefix(prefix: Path) -> Path:
    config = prefix / "share" / "by_your_command" / "config"
    config.mkdir(parents=True)
    audio_io = yaml.safe_load(find_config_file("audio_io.yaml").read_text())
    audio_io["/**/simple_audio_player"]["ros__parameters"] = PLAYER_SECTION
    (config / "audio_io.yaml").write_text(yaml.safe_dump(audio_io))
    vad = {
        "silero_vad_node": {"ros__parameters": VAD_SECTION},
        "clap_detector_node": {"ros__parameters": CLAP_SECTION},
    }
    (config / "vad.yaml").write_text(yaml.safe_dump(vad))
    return config
