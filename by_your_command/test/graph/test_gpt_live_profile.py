"""The gpt_live profile (issue 36): GPT-Live is full duplex, so its graph runs with the echo-cancelled
microphone (aec) by default and refuses a gated one before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from by_your_command.graph.model import Graph
from by_your_command.graph.options import parse_options
from by_your_command.graph.params import GraphError
from by_your_command.graph.processes import prepare
from by_your_command.graph.profiles import PROFILES, build_graph, launch_arguments

pytestmark = pytest.mark.unit


def graph_of(profile: str, **values: str) -> Graph:
    return build_graph(profile, parse_options(values, PROFILES[profile].defaults))


def test_the_profile_runs_one_gpt_live_agent_behind_the_echo_suppressor(config_dir: Path) -> None:
    graph = graph_of("gpt_live", audio_sink="wav:/tmp/reply.wav")
    assert [n.name for n in graph.nodes] == [
        "audio_capture",
        "echo_suppressor",  # aec: the VAD and the model hear the mic with the robot's voice removed
        "silero_vad_node",
        "clap_detector_node",
        "simple_audio_player",
        "ros_ai_bridge",
        "command_processor",
    ]  # no frame_forwarder: GPT-Live takes no images
    assert graph.node("echo_suppressor").parameters["mode"] == "aec"
    assert "input_topic" not in graph.node("silero_vad_node").parameters  # its default, audio_filtered
    [agent] = graph.agents
    assert Path(agent.config_file).name == "agent_gpt_live.yaml"
    assert agent.overrides["echo_mode"] == "aec" and agent.overrides["pause_timeout_s"] == 2.0


def test_the_launch_arguments_default_to_aec_and_the_gpt_live_provider() -> None:
    defaults = {a.name: a.default for a in launch_arguments("gpt_live")}
    assert defaults["echo_mode"] == "aec" and defaults["provider"] == "gpt_live"
    assert "cmd_model" not in defaults  # one agent


def test_a_gated_microphone_is_refused_naming_the_option() -> None:
    with pytest.raises(GraphError, match="option echo_mode: provider gpt_live is full duplex.*not gate"):
        graph_of("gpt_live", echo_mode="gate")
    with pytest.raises(GraphError, match="option echo_mode"):  # the provider, whatever the profile
        graph_of("oai_realtime", provider="gpt_live", echo_mode="gate")
    # external: the hardware cancels the echo; without agents the graph is only the voice nodes
    assert graph_of("gpt_live", echo_mode="external").agents
    assert graph_of("gpt_live", echo_mode="gate", agents="false").agents == ()


def test_gpt_live_has_no_dual_agents() -> None:
    with pytest.raises(GraphError, match="option provider: gpt_live has one agent.*profile gpt_live"):
        graph_of("oai_dual_agent", provider="gpt_live", echo_mode="aec")


def test_options_reach_the_agent_config(config_dir: Path, agent_dir: Path, tmp_path: Path) -> None:
    graph = graph_of(
        "gpt_live", agent_config_dir=str(agent_dir), model="gpt-live-2", voice="cedar", pause_timeout="5"
    )
    [agent] = graph.agents
    assert agent.config_file == f"{agent_dir}/agent_gpt_live.yaml"
    assert agent.overrides["provider"] == {"model": "gpt-live-2", "voice": "cedar"}
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    [process] = [p for p in prepare(graph, run_dir, which=lambda name: f"/bin/{name}") if p.is_agent]
    assert process.argv[:3] == ("/bin/byc", "agent", "--config")
