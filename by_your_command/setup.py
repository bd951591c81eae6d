"""ament_python package: executables go to lib/by_your_command so `ros2 run` finds them.

The same file builds a plain wheel (`pip install ./by_your_command`) for machines without ROS, where
agents run: config/*.yaml then ships inside the Python package too (config_files/locate.py finds it there).
"""

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
    "demo_robot": "by_your_command.nodes.demo_robot:main",  # a pretend robot: NavigateToPose, dock
    "audio_capture": "by_your_command.nodes.audio_capture:main",
    "echo_suppressor": "by_your_command.nodes.echo_suppressor:main",
    "simple_audio_player": "by_your_command.nodes.simple_audio_player:main",
    "oai_realtime_agent": "by_your_command.cli.agent:main_realtime",
    "oai_command_agent": "by_your_command.cli.agent:main_command",
    "gemini_live_agent": "by_your_command.cli.agent:main_gemini",
    "gemini_command_agent": "by_your_command.cli.agent:main_gemini_command",
}

# Ranges for users; the exact versions CI tests are pinned in requirements/*.txt (the lock).
# Lower bounds: the oldest releases with Python 3.10 wheels and the APIs the code uses (checked once
# by running the unit tests on Python 3.10 with exactly these versions; CI tests only the lock).
# numpy 1.x and 2.x both work: the code uses no numpy-2-only name, so ROS 2 Humble keeps its own
# python3-numpy (1.21.5), which packages such as cv_bridge are compiled against.
INSTALL_REQUIRES = [
    "numpy>=1.21",  # Humble's 1.21.5 (1.21.2: first Python 3.10 wheels)
    "scipy>=1.7.2",  # first release with Python 3.10 wheels
    "pyyaml>=6.0",
    "websockets>=15.0",  # websockets.asyncio, connect(proxy=...); apt's python3-websockets is 10.x
    "pillow>=10.3",  # Image.Resampling (9.1); 10.3 fixes CVE-2024-28219
    # 1.12: first with Python 3.10 wheels, and the last accepting numpy 1.21.5 (1.13+ need 1.21.6).
    # Built against numpy 1.x before 1.19; up to 1.18.0 without a numpy<2 cap (numpy 2: ImportError).
    "onnxruntime>=1.12",
    "openai>=3.52",  # GA realtime.connect; not the [realtime] extra (it caps websockets <16; 17.4 works)
    # The GPT-Live provider and emulator check events against the SDK's own models (openai needs
    # both; named because we import them): pydantic v2's API, typing_extensions' Required/NotRequired.
    "pydantic>=2.0",
    "typing-extensions>=4.7",
    "google-genai>=2.33",  # Gemini Live; 3.x needs Python 3.11, so 3.10 (Humble) gets 2.33
    "cryptography>=42",  # the Gemini emulator's self-signed certificate (the SDK forces TLS)
    "pocketsphinx>=5.0",  # offline recognition and spoken wake-up; the en-us model ships in the wheel
]
# Imported only where used. silero-vad (the VAD's ONNX model) is not listed: its own dependencies
# pull in torch, so it is installed with `pip install --no-deps "silero-vad>=6.2"` (README; the
# corpus tests are tuned to the 6.2 model, 6.0 and 6.1 miss utterances in noise).
EXTRAS_REQUIRE = {
    "audio": ["sounddevice>=0.4.6"],  # microphone and speaker devices (needs libportaudio2)
    # WebRTC AEC3; older releases fail test_echo (no high-pass). Every livekit needs numpy>=1.26.
    "aec": ["livekit>=1.1.4"],
}

setup(
    name=PACKAGE,
    version="0.1.0",
    python_requires=">=3.10",
    # config/ is also the Python package's `config` folder (package data): one copy in git.
    packages=[*find_packages(exclude=["test", "test.*"]), f"{PACKAGE}.config"],
    package_dir={f"{PACKAGE}.config": "config"},
    package_data={
        PACKAGE: ["py.typed"],
        f"{PACKAGE}.config": ["*.yaml"],
        f"{PACKAGE}.demo": ["*.wav", "*.sh"],  # the bundled demo speech and the script that makes it
        f"{PACKAGE}.monitor": ["static/*"],  # the live monitor page the bridge serves
    },
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    install_requires=INSTALL_REQUIRES,
    extras_require=EXTRAS_REQUIRE,
    zip_safe=False,
    maintainer="by_your_command maintainers",
    maintainer_email="maintainers@by-your-command.invalid",
    description="Voice and vision interaction for ROS 2 robots with realtime LLM agents",
    license="Apache-2.0",
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in EXECUTABLES.items()]},
)
