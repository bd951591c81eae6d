"""One OpenAI Realtime agent that talks and sends commands, with the full audio graph.

A thin wrapper: the graph (nodes, parameters, agents) is described once in by_your_command.graph,
which `byc up oai_realtime` starts too. Arguments and defaults:
    ros2 launch by_your_command oai_realtime.launch.py --show-args
"""

from launch import LaunchDescription

from by_your_command.graph.launch_actions import launch_description


def generate_launch_description() -> LaunchDescription:
    return launch_description("oai_realtime")
