"""One OpenAI GPT-Live agent that talks and acts, with the full audio graph.

GPT-Live is full duplex: it hears the microphone while it speaks and decides itself when the user
talks over it, so echo_mode defaults to aec (the robot's own voice cancelled); gate is refused. The
key comes from OPENAI_API_KEY. A thin wrapper: the graph (nodes, parameters, agents) is described
once in by_your_command.graph, which `byc up gpt_live` starts too. Arguments and defaults:
    ros2 launch by_your_command gpt_live.launch.py --show-args
"""

from launch import LaunchDescription

from by_your_command.graph.launch_actions import launch_description


def generate_launch_description() -> LaunchDescription:
    return launch_description("gpt_live")
