"""The graph description: which nodes and agents each profile starts, with which parameters."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from graph.graph_files import CLAP_SECTION, PLAYER_SECTION, VAD_SECTION

from by_your_command.graph.model import Graph
from by_your_command.graph.options import GraphOptions, parse_assignments, parse_options
from by_your_command.graph.params import GraphError
from by_your_command.graph.processes import agent_config, prepare
from by_your_command.graph.profiles import PROFILES, build_graph, launch_arguments

CORPUS = Path(__file__).resolve().parents[1] / "data" / "corpus"
WAV = CORPUS / "clean_en_us.wav"


def graph_of(profile: str, **values: str) -> Graph:
    return build_graph(profile, parse_options(values, PROFILES[profile].defaults))


@pytest.mark.unit
def test_voice_only_profile_from_a_file(config_dir: Path) -> None:
    graph = build_graph(
        "byc",
        parse_options(
            {
                "namespace": "grunt1",
                "prefix": "agent",
                "audio_source": f"file:{WAV}",
                "echo_mode": "external",
            },
            PROFILES["byc"].defaults,
        ),
    )
    assert graph.namespace == "/grunt1/agent"
    assert [n.name for n in graph.nodes] == [
        "file_audio_publisher",
        "silero_vad_node",  # gate and external need no echo_suppressor: the VAD reads `audio`
        "voice_recorder",  # the voice-only profile records by default, like the earlier byc.launch.py
    ]
    assert graph.agents == ()
    source = graph.node("file_audio_publisher").parameters
    assert source["files"] == [str(WAV)]
    assert source["min_subscribers"] == 1  # only the VAD listens to `audio` here
    # the config file's section, with ints turned into floats where the node declares a float
    vad = graph.node("silero_vad_node").parameters
    assert vad == {**VAD_SECTION, "threshold": 0.61, "input_topic": "audio", "echo_gate": False}
    assert graph.node("voice_recorder").executable == "voice_chunk_recorder"
    assert graph.node("voice_recorder").parameters == {"input_mode": "utterance", "output_dir": ""}


@pytest.mark.unit
def test_microphone_and_recorders(config_dir: Path, tmp_path: Path) -> None:
    graph = build_graph(
        "offline",
        parse_options(
            {
                "enable_voice_recorder": "true",
                "save_mic": "yes",
                "recordings_dir": str(tmp_path),
                "agents": "no",
            }
        ),
    )
    capture = graph.node("audio_capture")
    assert capture.param_sources == ("audio_io.yaml",) and capture.parameters["chunk"] == 1024
    assert graph.node("voice_recorder").parameters["output_dir"] == f"{tmp_path}/utterances"
    replies = graph.node("reply_recorder")
    assert replies.parameters == {"input_mode": "stream", "output_dir": f"{tmp_path}/replies"}
    mic = graph.node("mic_recorder")
    assert mic.remappings == (("response_voice", "audio"),)  # records what the microphone hears
    assert graph.agents == ()


@pytest.mark.unit
@pytest.mark.parametrize(
    ("profile", "extra", "agents", "vision"),
    [
        ("oai_realtime", [], ["agent_openai_tool.yaml"], False),
        ("oai_dual_agent", [], ["agent_openai.yaml", "agent_openai_command.yaml"], False),
        ("gemini_live", ["frame_forwarder"], ["agent_gemini_tool.yaml"], True),
        ("gemini_dual_agent", ["frame_forwarder"], ["agent_gemini.yaml", "agent_gemini_command.yaml"], True),
        ("offline", [], ["agent_offline.yaml"], False),
    ],
)
def test_agent_profiles(
    config_dir: Path, profile: str, extra: list[str], agents: list[str], vision: bool
) -> None:
    graph = build_graph(
        profile, parse_options({"audio_sink": "wav:/tmp/reply.wav"}, PROFILES[profile].defaults)
    )
    base = ["audio_capture", "silero_vad_node", "clap_detector_node"]  # gate: in the VAD
    services = ["simple_audio_player", "ros_ai_bridge", "command_processor"]
    assert [n.name for n in graph.nodes] == base + services + extra
    assert [Path(a.config_file).name for a in graph.agents] == agents
    assert all(a.executable == "byc" and a.arguments == ("agent",) for a in graph.agents)
    assert graph.node("clap_detector_node").parameters == CLAP_SECTION
    vad = graph.node("silero_vad_node").parameters
    assert vad["input_topic"] == "audio" and vad["echo_gate"] is True
    player = graph.node("simple_audio_player").parameters
    assert player == {**PLAYER_SECTION, "sink": "wav", "wav_path": "/tmp/reply.wav"}
    timeout = float(PROFILES[profile].defaults["pause_timeout"])
    assert all(a.overrides["pause_timeout_s"] == timeout for a in graph.agents)


@pytest.mark.unit
def test_agent_options_reach_the_agent_configs(config_dir: Path, agent_dir: Path) -> None:
    graph = build_graph(
        "oai_dual_agent",
        parse_options(
            {
                "agent_config_dir": str(agent_dir),
                "model": "gpt-new",
                "cmd_model": "gpt-mini",
                "voice": "echo",
                "pause_timeout": "42",
                "echo_mode": "aec",
                "bridge_port": "9191",
            },
            PROFILES["oai_dual_agent"].defaults,
        ),
    )
    conversation, command = (agent_config(agent) for agent in graph.agents)
    assert conversation == {
        "agent_id": "talker",
        "provider": {"model": "gpt-new", "voice": "echo"},
        "echo_mode": "aec",
        "pause_timeout_s": 42.0,
        "bridge": {"url": "ws://127.0.0.1:9191"},  # the agents find this graph's bridge
    }
    assert graph.node("ros_ai_bridge").parameters == {"port": 9191}
    assert command["provider"] == {"model": "gpt-mini"} and command["role"] == "command"
    assert graph.node("echo_suppressor").parameters["mode"] == "aec"
    assert graph.node("silero_vad_node").parameters.get("input_topic", "audio_filtered") == "audio_filtered"


@pytest.mark.unit
def test_node_parameter_overrides_win_and_are_checked(config_dir: Path) -> None:
    values = parse_assignments(["silero_vad_node.threshold=0.7", "silero_vad_node.start_awake=false"])
    graph = build_graph("byc", parse_options(values, PROFILES["byc"].defaults))
    vad = graph.node("silero_vad_node").parameters
    assert vad["threshold"] == 0.7 and vad["start_awake"] is False
    assert vad["min_silence_duration_ms"] == 300  # the rest still from the config file

    with pytest.raises(GraphError, match=r"silero_vad_node has no parameter 'thresold' \(set in --set"):
        graph_of("byc", **{"silero_vad_node.thresold": "0.7"})
    with pytest.raises(GraphError, match=r"silero_vad_node.threshold: must be float, got 'high'"):
        graph_of("byc", **{"silero_vad_node.threshold": "high"})
    with pytest.raises(GraphError, match=r"threshold must be in \(0, 1\)"):  # the node's own check
        graph_of("byc", **{"silero_vad_node.threshold": "1.5"})
    with pytest.raises(GraphError, match=r"no node 'simple_audio_player' in profile 'byc'"):
        graph_of("byc", **{"simple_audio_player.sink": "wav"})


@pytest.mark.unit
def test_a_config_file_naming_an_unknown_parameter_is_refused(config_dir: Path) -> None:
    (config_dir / "vad.yaml").write_text(yaml.safe_dump({"silero_vad_node": {"ros__parameters": {"zcr": 1}}}))
    with pytest.raises(GraphError, match=r"no parameter 'zcr' \(set in config/vad.yaml\)"):
        graph_of("byc")


@pytest.mark.unit
@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"namespace": "robot 1"}, "not a ROS namespace"),
        ({"echo_mode": "loud"}, "echo_mode: one of gate, aec, external"),
        ({"audio_source": "file:/no/such.wav"}, "no such file /no/such.wav"),
        ({"audio_source": "line-in"}, "mic or file:<wav path>"),
        ({"audio_sink": "wav:"}, "needs a path"),
        ({"save_mic": "maybe"}, "not a boolean"),
        ({"pause_timeout": "-1"}, "must be > 0"),
        ({"bridge_port": "70000"}, "bridge_port: 1..65535"),
        ({"bridge_port": "x"}, "option bridge_port: invalid literal"),
        ({"volume": "11"}, "unknown option 'volume'"),
    ],
)
def test_bad_options_are_refused_with_a_reason(values: dict[str, str], message: str) -> None:
    with pytest.raises(GraphError, match=message):
        parse_options(values)


@pytest.mark.unit
def test_launch_arguments_follow_the_profile() -> None:
    voice = {a.name: a.default for a in launch_arguments("byc")}
    assert voice["enable_voice_recorder"] == "true" and "model" not in voice and "audio_sink" not in voice
    dual = {a.name: a.default for a in launch_arguments("gemini_dual_agent")}
    assert dual["pause_timeout"] == "2.0" and dual["provider"] == "gemini" and dual["cmd_model"] == ""
    assert "cmd_model" not in {a.name for a in launch_arguments("oai_realtime")}
    for name in ("namespace", "prefix", "enable_voice_recorder", "save_mic", "echo_mode", "voice", "model"):
        assert name in dual
    # every argument parses back to the defaults of GraphOptions' fields
    assert parse_options(dual) == parse_options({}, PROFILES["gemini_dual_agent"].defaults)


@pytest.mark.unit
def test_missing_agent_config_says_what_is_missing(config_dir: Path, tmp_path: Path) -> None:
    graph = graph_of("offline", agent_config_dir=str(tmp_path))
    with pytest.raises(GraphError) as raised:
        prepare(graph, tmp_path, which=lambda name: f"/bin/{name}")
    assert "agent agent: config file missing" in str(raised.value)
    assert "agent_offline.yaml" in str(raised.value)
    assert "byc up offline --no-agents" in str(raised.value)


@pytest.mark.unit
def test_processes_carry_namespace_params_and_remappings(
    config_dir: Path, agent_dir: Path, tmp_path: Path
) -> None:
    options = parse_options(
        {"namespace": "r2", "save_mic": "true", "agent_config_dir": str(agent_dir)},
        PROFILES["offline"].defaults,
    )
    graph = build_graph("offline", options)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    processes = {p.name: p for p in prepare(graph, run_dir, which=lambda name: f"/opt/bin/{name}")}
    assert set(processes) == {n.name for n in graph.nodes} | {"agent"}
    mic = processes["mic_recorder"].argv
    assert mic[:6] == (
        "/opt/bin/voice_chunk_recorder",
        "--ros-args",
        "-r",
        "__node:=mic_recorder",
        "-r",
        "__ns:=/r2",
    )
    assert mic[-2:] == ("-r", "response_voice:=audio")
    vad = processes["silero_vad_node"].argv
    params = yaml.safe_load(Path(vad[vad.index("--params-file") + 1]).read_text())
    # keyed /**: applies in any namespace (bare node names in a params file apply only at the root)
    assert params == {"/**": {"ros__parameters": graph.node("silero_vad_node").parameters}}
    agent = processes["agent"]
    assert agent.is_agent and agent.argv[:3] == ("/opt/bin/byc", "agent", "--config")
    assert yaml.safe_load(Path(agent.argv[3]).read_text())["agent_id"] == "offline"


@pytest.mark.unit
def test_every_profile_builds_from_the_shipped_config_files() -> None:
    """The shipped config files name only parameters the nodes declare (else ROS ignores them)."""
    for name in PROFILES:
        build_graph(name, parse_options({}, PROFILES[name].defaults))


@pytest.mark.unit
def test_default_options_match_the_dataclass() -> None:
    assert parse_options({}) == GraphOptions()
