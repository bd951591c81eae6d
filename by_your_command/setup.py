"""ament_python package: executables go to lib/by_your_command so `ros2 run` finds them."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "by_your_command"

# One line per executable: `ros2 run by_your_command <name>` and install/lib/by_your_command/<name>.
EXECUTABLES = {
    "silero_vad_node": "by_your_command.nodes.silero_vad_node:main",
    "clap_detector_node": "by_your_command.nodes.clap_detector_node:main",
    "voice_chunk_recorder": "by_your_command.nodes.voice_chunk_recorder:main",
    "file_audio_publisher": "by_your_command.nodes.file_audio_publisher:main",
    "byc": "by_your_command.cli.byc:main",
    "command_processor": "by_your_command.nodes.command_processor:main",
    "expand_prompt": "by_your_command.cli.expand_prompt:main",
    "publish_command": "by_your_command.cli.publish_command:main",
    "ros_ai_bridge": "by_your_command.nodes.ros_ai_bridge:main",
    "frame_forwarder": "by_your_command.nodes.frame_forwarder:main",
    "audio_capture": "by_your_command.nodes.audio_capture:main",
    "echo_suppressor": "by_your_command.nodes.echo_suppressor:main",
    "simple_audio_player": "by_your_command.nodes.simple_audio_player:main",
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="by_your_command maintainers",
    maintainer_email="maintainers@by-your-command.invalid",
    description="Voice and vision interaction for ROS 2 robots with realtime LLM agents",
    license="Apache-2.0",
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in EXECUTABLES.items()]},
)
