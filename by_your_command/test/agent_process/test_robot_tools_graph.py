"""The robot's own tools end to end (docs/tools.md): `byc agent` (OpenAI and Gemini emulators through
the official SDKs, and the offline provider) → ros_ai_bridge (tools file, rosbridge service and
action operations) → demo_robot's real rclpy action and service servers, and back to the model."""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import pytest
import yaml
from agent_graph import (
    CONFIG_DIR,
    AgentGraph,
    agent_config,
    agent_process,
    alive,
    bridge_process,
    demo_robot_process,
    emulator,
    gemini_emulator,
    gemini_graph,
    graph_probe,
    setup_requests,
    until,
)
from by_your_command_msgs.msg import SafetyStop

from by_your_command.emulators import gemini_script, openai_script
from by_your_command.emulators.gemini_wire import field_value

pytestmark = [pytest.mark.ros, pytest.mark.timeout(240)]

MS_PER_CHAR = 40
WAIT_S = 90.0
GO_TO = json.dumps({"place": "kitchen"})
TOOLS = """
tools:
  go_to:
    description: Drive to one of the named places and stop there.
    action: navigate_to_pose
    type: by_your_command_msgs/action/NavigateToPose
    fixed: {pose.header.frame_id: map}
    arguments:
      place:
        description: where to go
        choices:
          kitchen: {pose.pose.position.x: 2.0, pose.pose.orientation.w: 1.0}
    feedback: {every_s: 0.5, fields: [distance_remaining]}
    timeout_s: 10
    spoken: ["go to the {place}"]
  battery:
    description: The battery level.
    service: battery_status
    type: by_your_command_msgs/srv/Trigger
    while_asleep: true
"""


@pytest.fixture
def tools_file(tmp_path: Path) -> Path:
    path = tmp_path / "tools.yaml"
    path.write_text(TOOLS, encoding="utf-8")
    return path


def tool_records(graph_probe_records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [record for record in graph_probe_records if record["record"] == "tool_call"]


def states(records: list[dict[str, Any]]) -> list[str]:
    return [record["state"] for record in tool_records(records)]


@contextmanager
def openai_tools_graph(
    namespace: str, tmp_path: Path, tools: Path, script: openai_script.Script, *robot_params: str
) -> Iterator[tuple[Any, Any, Any]]:
    """The OpenAI emulator, the probe, demo_robot (`robot_params` name:=value), the bridge with
    `tools`, and `byc agent` holding the robot's tools."""
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe = stack.enter_context(graph_probe(namespace))
        robot = stack.enter_context(demo_robot_process(namespace, "feedback_rate_hz:=10.0", *robot_params))
        port, _ = stack.enter_context(bridge_process(namespace, 0, f"tools_path:={tools}"))
        config, settings = agent_config(tmp_path, openai.url, "robot", role="tools")
        agent, output = stack.enter_context(agent_process(config, port))
        check = alive(agent, robot)
        probe.wait_agents_ready(namespace, [setup_requests(settings)])
        until(lambda: output.find(r"the robot's tools: .*go_to"), "the agent got the tools", check, WAIT_S)
        yield openai, probe, check


def wait_driving(probe: Any, check: Any) -> None:
    """Until the agent told the model the robot's first feedback: the goal is running."""
    until(
        lambda: any(r.get("progress") for r in tool_records(probe.metric_records())),
        "the robot driving (feedback told)",
        check,
        WAIT_S,
    )


def function_outputs(openai: Any) -> list[dict[str, Any]]:
    return [
        json.loads(event["item"]["output"])
        for event in openai.events("conversation.item.create")
        if event["item"]["type"] == "function_call_output"
    ]


def notes(openai: Any) -> list[str]:
    return [
        part["text"]
        for event in openai.events("conversation.item.create")
        if event["item"]["type"] == "message"
        for part in event["item"]["content"]
        if part.get("type") == "input_text"
    ]


def test_openai_a_goal_drives_reports_progress_and_its_result_gets_the_reply(
    ros_namespace: str, tmp_path: Path, tools_file: Path
) -> None:
    script = openai_script.Script(
        turns=(
            openai_script.Turn(
                openai_script.CallTool("go_to", GO_TO, openai_script.Say("I am in the kitchen."))
            ),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    with openai_tools_graph(ros_namespace, tmp_path, tools_file, script, "speed_mps:=1.0") as (
        openai,
        probe,
        check,
    ):
        probe.type_text("go to the kitchen")
        until(
            lambda: "I am in the kitchen." in probe.texts(probe.replies),
            "the reply after arriving",
            check,
            WAIT_S,
        )

        tools = {tool["name"]: tool for tool in openai.events("session.update")[0]["session"]["tools"]}
        assert set(tools) == {"robot_command", "go_to", "battery"}
        assert tools["go_to"]["parameters"]["properties"]["place"]["enum"] == ["kitchen"]
        [result] = function_outputs(openai)
        assert result["ok"] is True and result["status"] == "succeeded"
        progress = [note for note in notes(openai) if note.startswith("go_to in progress")]
        assert progress and "distance_remaining" in progress[0]  # the robot's feedback, told to the model
        assert probe.texts(probe.replies) == ["I am in the kitchen."]  # the result's reply, once
        assert (
            states(probe.metric_records())[0] == "running"
            and states(probe.metric_records())[-1] == "succeeded"
        )


def test_openai_stop_typed_while_driving_cancels_the_goal_and_the_model_hears_why(
    ros_namespace: str, tmp_path: Path, tools_file: Path
) -> None:
    script = openai_script.Script(
        turns=(
            openai_script.Turn(
                openai_script.CallTool("go_to", GO_TO, openai_script.Say("I stopped before the kitchen."))
            ),
            openai_script.Turn(openai_script.Say("Stopping.")),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    with openai_tools_graph(ros_namespace, tmp_path, tools_file, script, "speed_mps:=0.05") as (
        openai,
        probe,
        check,
    ):
        probe.type_text("go to the kitchen")
        wait_driving(probe, check)
        probe.type_text("stop")
        until(lambda: function_outputs(openai), "the goal's end", check, WAIT_S)
        [result] = function_outputs(openai)
        assert result["ok"] is False and result["status"] == "cancelled"
        assert "stop" in result["error"]
        until(
            lambda: "I stopped before the kitchen." in probe.texts(probe.replies),
            "the reply to the cancelled goal",
            check,
            WAIT_S,
        )
        assert states(probe.metric_records())[-1] == "cancelled"


def test_gemini_non_blocking_goal_progress_is_silent_and_the_result_comes_when_idle(
    ros_namespace: str, tmp_path: Path, tools_file: Path
) -> None:
    script = gemini_script.Script(
        turns=(
            gemini_script.Turn(
                gemini_script.CallTool("go_to", GO_TO, gemini_script.Say("I am in the kitchen."))
            ),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    with ExitStack() as stack:
        api = stack.enter_context(gemini_emulator(script))
        stack.enter_context(demo_robot_process(ros_namespace, "speed_mps:=1.0", "feedback_rate_hz:=10.0"))
        graph: AgentGraph = stack.enter_context(
            gemini_graph(
                ros_namespace,
                tmp_path,
                [(api, "agent_gemini_tool.yaml", {})],
                bridge_params=(f"tools_path:={tools_file}",),
            )
        )
        probe, check = graph.probe, graph.check
        output = graph.agents[0].output
        until(lambda: output.find(r"the robot's tools: .*go_to"), "the agent got the tools", check, WAIT_S)
        probe.type_text("go to the kitchen")
        until(
            lambda: "I am in the kitchen." in probe.texts(probe.replies),
            "the reply after arriving",
            check,
            WAIT_S,
        )

        declarations = {
            d["name"]: d
            for tool in field_value(api.bodies("setup")[-1], "tools")
            for d in field_value(tool, "functionDeclarations") or []
        }
        assert declarations["go_to"]["behavior"] == "NON_BLOCKING"
        assert declarations["battery"]["behavior"] == "BLOCKING"
        responses = [r for body in api.bodies("toolResponse") for r in field_value(body, "functionResponses")]
        progress, final = responses[:-1], responses[-1]
        assert progress and all(
            field_value(r, "willContinue") and field_value(r, "scheduling") == "SILENT" for r in progress
        )
        assert field_value(final, "scheduling") == "WHEN_IDLE" and not field_value(final, "willContinue")
        assert final["response"]["status"] == "succeeded"
        assert probe.texts(probe.replies) == ["I am in the kitchen."]


def test_offline_agent_hears_a_tool_phrase_and_says_the_services_answer(
    ros_namespace: str, tmp_path: Path, tools_file: Path
) -> None:
    data = yaml.safe_load((CONFIG_DIR / "agent_offline.yaml").read_text())
    data.update(agent_id="offline", pause_timeout_s=60.0)
    tools = yaml.safe_load(TOOLS)
    tools["tools"]["battery"]["spoken"] = ["battery status"]
    tools_file.write_text(yaml.safe_dump(tools), encoding="utf-8")
    config = tmp_path / "offline.yaml"
    config.write_text(yaml.safe_dump(data))
    with ExitStack() as stack:
        probe = stack.enter_context(graph_probe(ros_namespace))
        robot = stack.enter_context(demo_robot_process(ros_namespace, "battery_percent:=64.0"))
        port, _ = stack.enter_context(bridge_process(ros_namespace, 0, f"tools_path:={tools_file}"))
        agent, output = stack.enter_context(agent_process(config, port))
        check = alive(agent, robot)
        probe.wait_agents_ready(ros_namespace, [setup_requests(data)], 90.0)
        until(lambda: output.find(r"the robot's tools: .*go_to"), "the agent got the tools", check, WAIT_S)
        probe.type_text("battery status")
        until(lambda: probe.replies, "the spoken answer", check, WAIT_S)
        [reply] = probe.texts(probe.replies)
        assert "64" in reply  # demo_robot's own message, said by the offline agent
        assert states(probe.metric_records()) == ["running", "succeeded"]


def test_openai_the_robots_refusals_and_silences_reach_the_model_plainly(
    ros_namespace: str, tmp_path: Path
) -> None:
    """A goal the server rejects, an action nobody serves, a service slower than its timeout."""
    tools = yaml.safe_load(TOOLS)
    go_to = tools["tools"]["go_to"]
    go_to["arguments"]["place"]["choices"]["the moon"] = {
        "pose.pose.position.x": 500.0
    }  # beyond max_distance_m
    tools["tools"]["ghost_drive"] = {**go_to, "action": "nobody_drives", "timeout_s": 1, "spoken": []}
    tools["tools"]["battery"]["timeout_s"] = 1
    tools_file = tmp_path / "tools.yaml"
    tools_file.write_text(yaml.safe_dump(tools), encoding="utf-8")
    say = openai_script.Say
    script = openai_script.Script(
        turns=(
            openai_script.Turn(
                openai_script.CallTool("go_to", json.dumps({"place": "the moon"}), say("Refused."))
            ),
            openai_script.Turn(openai_script.CallTool("ghost_drive", GO_TO, say("Nobody drives."))),
            openai_script.Turn(openai_script.CallTool("battery", "{}", say("No answer."))),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    graph = openai_tools_graph(ros_namespace, tmp_path, tools_file, script, "service_delay_s:=5.0")
    with graph as (openai, probe, check):
        for count, text in enumerate(("go to the moon", "drive nowhere", "battery?"), start=1):
            probe.type_text(text)
            until(lambda: len(probe.replies) >= count, f"the reply to {text!r}", check, WAIT_S)  # noqa: B023
        statuses = [(r["status"], r["error"]) for r in function_outputs(openai)]
        assert [status for status, _ in statuses] == ["rejected", "unavailable", "timeout"], statuses
        assert probe.texts(probe.replies) == ["Refused.", "Nobody drives.", "No answer."]


def test_openai_the_safety_stop_reaches_the_agent_through_the_bridge_and_ends_the_goal(
    ros_namespace: str, tmp_path: Path, tools_file: Path
) -> None:
    """`safety_stop` (what the VAD's spotter publishes): the bridge and the agent cancel the goal,
    and the model is told that the robot stopped (a note, no reply asked for it)."""
    script = openai_script.Script(
        turns=(openai_script.Turn(openai_script.CallTool("go_to", GO_TO, openai_script.Say("I stopped."))),),
        ms_per_char=MS_PER_CHAR,
    )
    with openai_tools_graph(ros_namespace, tmp_path, tools_file, script, "speed_mps:=0.05") as (
        openai,
        probe,
        check,
    ):
        probe.type_text("go to the kitchen")
        wait_driving(probe, check)
        probe.safety_stop.publish(SafetyStop(phrase="stop"))
        until(lambda: function_outputs(openai), "the goal's end", check, WAIT_S)
        [result] = function_outputs(openai)
        assert result["ok"] is False and result["status"] == "cancelled"
        until(
            lambda: "I stopped." in probe.texts(probe.replies),
            "the reply to the cancelled goal",
            check,
            WAIT_S,
        )
        assert any("the robot heard this itself and stopped" in note for note in notes(openai))
