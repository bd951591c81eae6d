"""Voice detection only: microphone (or a WAV file), echo control, Silero VAD, utterance recorder.

A thin wrapper: the graph (nodes, parameters, agents) is described once in by_your_command.graph,
which `byc up byc` starts too. Arguments and defaults:
    ros2 launch by_your_command byc.launch.py --show-args
"""

from launch import LaunchDescription

from by_your_command.graph.launch_actions import launch_description


def generate_launch_description() -> LaunchDescription:
    return launch_description("byc")
