"""Helpers for the agent process tests: the OpenAI and Gemini emulators on their own event-loop
thread (so a synchronous test can read what the agent sent), node and agent processes with their
output collected, and a probe node that plays the microphone side and records every output topic."""

from __future__ import annotations

import asyncio
import base64
import json
import re
import shutil
import signal
import subprocess
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from by_your_command_msgs.msg import (
    AudioDataUtterance,
    CommandRequest,
    CommandVerdict,
    Interruption,
    PlaybackStatus,
    SafetyStop,
)
from byc_testing import REPO_ROOT, python_module, running_process, wait_for
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import QoSHistoryPolicy, QoSProfile, QoSReliabilityPolicy
from ros_probe import Probe, probe_node
from std_msgs.msg import Bool, String

from by_your_command.agents.bridge_port import BridgePort
from by_your_command.agents.config import parse_agent_config
from by_your_command.audio.pcm import read_wav
from by_your_command.emulators import gemini_live
from by_your_command.emulators.gemini_script import Script as GeminiScript
from by_your_command.emulators.gemini_wire import decode_blob, field_value
from by_your_command.emulators.openai_realtime import OpenAIRealtimeEmulator, ReceivedEvent, start
from by_your_command.emulators.openai_script import Script
from by_your_command.emulators.threaded import ThreadedEmulator
from by_your_command.nodes._qos import LATCHED, RELIABLE

DEEP = QoSProfile(history=QoSHistoryPolicy.KEEP_LAST, depth=2000, reliability=QoSReliabilityPolicy.RELIABLE)

# Recognisable, so a test can prove it never reaches any log line.
FAKE_KEY = "sk-test-Rec0gnisableFakeKey-7f3a9c1e5b"
CORPUS = REPO_ROOT / "by_your_command" / "test" / "data" / "corpus"
CONFIG_DIR = REPO_ROOT / "by_your_command" / "config"
VAD_RATE = 16000
BRIDGE_OUTPUTS = (
    "prompt_transcript",
    "response_text",
    "response_cmd",
    "command_request",
    "interruption_signal",
    "agent_metrics",
)


def corpus_utterance(index: int = 0, session: str = "clean_en_us") -> np.ndarray:
    """One spoken segment of the test corpus (16 kHz mono), as the VAD would cut it."""
    segments = json.loads((CORPUS / "segments.json").read_text())["sessions"][session]["segments"]
    samples, rate, _ = read_wav(CORPUS / f"{session}.wav")
    assert rate == VAD_RATE
    segment = segments[index]
    return samples[int(segment["start"] * rate) : int(segment["end"] * rate)]


# --- the emulator ------------------------------------------------------------------------------


class EmulatorThread(ThreadedEmulator[OpenAIRealtimeEmulator]):
    """`emulators.openai_realtime` served from a private loop; every read hops onto that loop."""

    def __init__(self, script: Script) -> None:
        super().__init__(start(script=script))
        self.url = self.handle.websocket_base_url

    def received(self) -> list[ReceivedEvent]:
        return self._read(lambda: list(self.handle.received))

    def events(self, type_: str) -> list[dict[str, Any]]:
        return [record.event for record in self.received() if record.event["type"] == type_]

    def types(self) -> list[str]:
        return [str(record.event["type"]) for record in self.received()]

    def connections(self) -> int:
        return self._read(lambda: len(self.handle.handshakes))

    def open_connections(self) -> int:
        return self._read(lambda: self.handle.open_connections)

    def appended_ms(self) -> float:
        """Milliseconds of 24 kHz PCM the client appended to the input buffer."""
        total = sum(len(base64.b64decode(e["audio"])) for e in self.events("input_audio_buffer.append"))
        return total / 48.0


def emulator(script: Script) -> EmulatorThread:
    """The emulator, running; leaving its `with` block stops it."""
    return EmulatorThread(script)


class GeminiEmulatorThread(ThreadedEmulator[gemini_live.GeminiLiveEmulator]):
    """`emulators.gemini_live` (TLS, a certificate made at start) served from a private loop."""

    def __init__(self, script: GeminiScript) -> None:
        super().__init__(gemini_live.start(script=script))
        self.base_url = self.handle.base_url
        self.ca_file = str(self.handle.cert_file)

    def received(self, connection: int | None = None) -> list[gemini_live.ReceivedMessage]:
        records = self._read(lambda: list(self.handle.received))
        return [r for r in records if connection is None or r.connection == connection]

    def bodies(self, kind: str, connection: int | None = None) -> list[dict[str, Any]]:
        return [r.body for r in self.received(connection) if r.kind == kind]

    def steps(self, connection: int | None = None) -> list[str]:
        """What the client sent, in order, one name per part: setup, clientContent, toolResponse,
        and for realtimeInput each of activityStart, audio, video, text, activityEnd."""
        out: list[str] = []
        for record in self.received(connection):
            if record.kind != "realtimeInput":
                out.append(record.kind)
                continue
            parts = ("activityStart", "audio", "video", "text", "activityEnd", "audioStreamEnd")
            out += [part for part in parts if field_value(record.body, part) is not None]
        return out

    def frames(self, connection: int | None = None) -> list[bytes]:
        """Every camera frame sent (realtimeInput.video), decoded, in order."""
        return [
            decode_blob(field_value(field_value(body, "video"), "data"), "video")
            for body in self.bodies("realtimeInput", connection)
            if field_value(body, "video") is not None
        ]

    def audio(self, connection: int | None = None) -> bytes:
        """The PCM the client sent as realtime audio (16 kHz)."""
        return b"".join(
            decode_blob(field_value(field_value(body, "audio"), "data"), "audio")
            for body in self.bodies("realtimeInput", connection)
            if field_value(body, "audio") is not None
        )

    def connections(self) -> int:
        return self._read(lambda: len(self.handle.handshakes))

    def handshakes(self) -> list[gemini_live.Handshake]:
        return self._read(lambda: list(self.handle.handshakes))

    def closes(self) -> list[gemini_live.Closed]:
        return self._read(lambda: list(self.handle.closes))

    def audio_outside_activity_ms(self) -> int:
        return self._read(lambda: sum(s.audio_outside_activity_ms for s in self.handle.sessions.values()))


def gemini_emulator(script: GeminiScript) -> GeminiEmulatorThread:
    """The emulator, running; leaving its `with` block stops it."""
    return GeminiEmulatorThread(script)


# --- processes ---------------------------------------------------------------------------------


class Output:
    """A process's output lines, collected on a thread so tests can wait on them."""

    def __init__(self, process: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._pump, args=(process,), daemon=True)
        self._thread.start()

    def _pump(self, process: subprocess.Popen[str]) -> None:
        assert process.stdout is not None
        for line in process.stdout:
            self.lines.append(line.rstrip("\n"))

    def find(self, pattern: str) -> re.Match[str] | None:
        return next((m for line in list(self.lines) if (m := re.search(pattern, line))), None)

    def finish(self) -> list[str]:
        """All lines, once the process has exited."""
        self._thread.join(timeout=10)
        return self.lines

    def __str__(self) -> str:
        return "\n".join(self.lines[-60:])


@dataclass
class Bridge:
    port: int
    process: subprocess.Popen[str]
    output: Output

    def kill(self) -> None:
        """SIGKILL: no close frames, no DDS goodbye; the kernel resets its sockets."""
        self.process.send_signal(signal.SIGKILL)
        self.process.wait(timeout=10)


@contextmanager
def bridge(namespace: str, port: int = 0, *params: str) -> Iterator[Bridge]:
    """ros_ai_bridge as a process (its handle kept, so a test can kill it); `params` name:=value."""
    args = [arg for param in ("diagnostics_period_s:=0.2", f"port:={port}", *params) for arg in ("-p", param)]
    command = python_module(
        "by_your_command.nodes.ros_ai_bridge", "--ros-args", "-r", f"__ns:={namespace}", *args
    )
    with running_process(command) as process:
        output = Output(process)
        match = wait_for(
            lambda: output.find(r"listening on 127\.0\.0\.1:(\d+)") or process.poll() is not None,
            timeout=60,
            what="bridge startup",
        )
        assert isinstance(match, re.Match), str(output)
        yield Bridge(int(match.group(1)), process, output)


@contextmanager
def bridge_process(namespace: str, port: int = 0, *params: str) -> Iterator[tuple[int, Output]]:
    with bridge(namespace, port, *params) as running:
        yield running.port, running.output


@contextmanager
def demo_robot(namespace: str, *params: str) -> Iterator[tuple[subprocess.Popen[str], Output]]:
    """demo_robot (a pretend robot: navigate_to_pose, dock, battery_status) with its log kept: it
    says which pose each goal asked for. `params` name:=value."""
    args = [arg for param in params for arg in ("-p", param)]
    command = python_module(
        "by_your_command.nodes.demo_robot", "--ros-args", "-r", f"__ns:={namespace}", *args
    )
    with running_process(command) as process:
        output = Output(process)
        wait_for(
            lambda: output.find("demo_robot ready") or process.poll() is not None,
            timeout=60,
            what="demo_robot startup",
        )
        assert output.find("demo_robot ready"), str(output)
        try:
            yield process, output
        finally:  # pytest shows captured stdout only when the test failed
            print("--- demo_robot:", *list(output.lines), sep="\n")


@contextmanager
def demo_robot_process(namespace: str, *params: str) -> Iterator[subprocess.Popen[str]]:
    """demo_robot, when its log is not needed."""
    with demo_robot(namespace, *params) as (process, _):
        yield process


@contextmanager
def player_process(namespace: str, wav: Path) -> Iterator[subprocess.Popen[str]]:
    """The player with a WAV sink at the provider's 24 kHz, paced like a device."""
    command = python_module(
        "by_your_command.nodes.simple_audio_player",
        "--ros-args", "-r", f"__ns:={namespace}",
        "-p", "sink:=wav", "-p", f"wav_path:={wav}", "-p", "sample_rate:=24000", "-p", "realtime:=true",
    )  # fmt: skip
    with running_process(command) as process:
        yield process


@contextmanager
def processor_process(namespace: str) -> Iterator[subprocess.Popen[str]]:
    command = python_module(
        "by_your_command.nodes.command_processor", "--ros-args", "-r", f"__ns:={namespace}",
        "-p", "min_interval_s:=0.0",
    )  # fmt: skip
    with running_process(command) as process:
        yield process


@contextmanager
def frame_forwarder_process(namespace: str, *params: str) -> Iterator[subprocess.Popen[str]]:
    """frame_forwarder on camera/image_raw (raw frames) → camera_forwarded; `params` as name:=value."""
    args = [arg for param in params for arg in ("-p", param)]
    command = python_module(
        "by_your_command.nodes.frame_forwarder", "--ros-args", "-r", f"__ns:={namespace}", *args
    )
    with running_process(command) as process:
        yield process


def agent_config(
    tmp_path: Path, emulator_url: str, agent_id: str = "talker", **settings: Any
) -> tuple[Path, dict[str, Any]]:
    """An agent config file pointed at an emulator; `settings` are AgentConfig keys."""
    data: dict[str, Any] = {
        "agent_id": agent_id,
        "pause_timeout_s": 60.0,  # no session cycling in the middle of a test unless it asks
        **settings,
        "provider": {"type": "openai", "websocket_base_url": emulator_url, **settings.get("provider", {})},
    }
    path = tmp_path / f"{agent_id}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path, data


def shipped_agent_config(
    tmp_path: Path, shipped: str, endpoint: dict[str, Any], **settings: Any
) -> tuple[Path, dict[str, Any]]:
    """A shipped agent config (config/`shipped`) pointed at an emulator (`endpoint`: the provider
    keys that reach it); `settings` override AgentConfig keys, `provider` is merged into the provider's."""
    data: dict[str, Any] = yaml.safe_load((CONFIG_DIR / shipped).read_text())
    provider = {**data["provider"], **endpoint}
    data.update(pause_timeout_s=60.0)  # no session cycling in the middle of a test unless it asks
    data.update(settings)
    data["provider"] = {**provider, **settings.get("provider", {})}
    path = tmp_path / f"{data['agent_id']}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path, data


def gemini_agent_config(
    tmp_path: Path, api: GeminiEmulatorThread, shipped: str = "agent_gemini.yaml", **settings: Any
) -> tuple[Path, dict[str, Any]]:
    """A shipped Gemini agent config pointed at the emulator (its base URL and certificate)."""
    endpoint = {"base_url": api.base_url, "ca_file": api.ca_file}
    return shipped_agent_config(tmp_path, shipped, endpoint, **settings)


# Agents started (agent_process, installed_gemini_agent) and not yet seen subscribed at the bridge:
# wait_agents_ready fails at once, with its output, when one of them has exited (else it waited its
# whole timeout for a client that would never come). Agents a test kills later are not in it.
_STARTING: list[tuple[subprocess.Popen[str], Output]] = []


@contextmanager
def _starting(process: subprocess.Popen[str], output: Output) -> Iterator[None]:
    entry = (process, output)
    _STARTING.append(entry)
    try:
        yield
    finally:
        if entry in _STARTING:
            _STARTING.remove(entry)


def _check_starting_agents() -> None:
    for process, output in list(_STARTING):
        if process.poll() is not None:
            output.finish()  # the lines it wrote before it exited
            raise AssertionError(
                f"agent {process.args!r} exited with {process.returncode} before it subscribed at "
                f"the bridge:\n{output}"
            )


@contextmanager
def agent_process(
    config: Path, bridge_port: int, key: str = FAKE_KEY, *options: str
) -> Iterator[tuple[subprocess.Popen[str], Output]]:
    command = python_module("by_your_command.cli.byc", "agent", "--config", str(config), *options)
    # Every provider's key variable, so no real key from the caller's environment is ever used.
    keys = {name: key for name in ("OPENAI_API_KEY", "GOOGLE_API_KEY", "GEMINI_API_KEY")}
    env = {**keys, "BYC_BRIDGE_URL": f"ws://127.0.0.1:{bridge_port}"}
    with running_process(command, env=env) as process, _starting(process, output := Output(process)):
        try:
            yield process, output
        finally:  # pytest shows captured stdout only when the test failed: the agent's own story
            print(f"--- {config.name}:", *list(output.lines), sep="\n")


# The installed executables (`ros2 run by_your_command NAME`) and the shipped config each defaults to.
GEMINI_EXECUTABLES = {
    "agent_gemini.yaml": "gemini_live_agent",
    "agent_gemini_command.yaml": "gemini_command_agent",
}
KEY_VARIABLES = ("OPENAI_API_KEY", "GOOGLE_API_KEY", "GEMINI_API_KEY")


def installed_executable(name: str) -> str:
    """An executable as colcon installed it (install/by_your_command/lib/by_your_command/, on PATH
    through scripts/env.sh): what `ros2 run by_your_command NAME` starts."""
    executable = shutil.which(name)
    assert executable is not None, f"{name} is not on PATH: run scripts/bootstrap.sh"
    return executable


@contextmanager
def installed_gemini_agent(
    name: str, api: GeminiEmulatorThread, bridge_port: int, key_env: str = "GOOGLE_API_KEY"
) -> Iterator[tuple[subprocess.Popen[str], Output]]:
    """The installed executable `name` on its default config, pointed at the emulator with --set and
    given ROS arguments (which it ignores), with the key in `key_env` only: the other key variables
    are removed from its environment (not blanked)."""
    unset = [arg for variable in KEY_VARIABLES if variable != key_env for arg in ("-u", variable)]
    command = [
        "env", *unset, installed_executable(name),
        "--set", f"provider.base_url={api.base_url}", "--set", f"provider.ca_file={api.ca_file}",
        "--pause-timeout", "60", "--ros-args", "-r", f"__node:={name}",
    ]  # fmt: skip
    env = {key_env: FAKE_KEY, "BYC_BRIDGE_URL": f"ws://127.0.0.1:{bridge_port}"}
    with running_process(command, env=env) as process, _starting(process, output := Output(process)):
        try:
            yield process, output
        finally:
            print(f"--- {name}:", *list(output.lines), sep="\n")


def setup_requests(settings: dict[str, Any]) -> int:
    """How many subscribe + advertise requests an agent with these settings sends at connect."""

    class Counter:
        requests = 0

        async def subscribe(self, topic: str, msg_type: str | None = None) -> None:
            self.requests += 1

        async def advertise(self, topic: str, msg_type: str) -> None:
            self.requests += 1

    counter = Counter()
    agent = {key: value for key, value in settings.items() if key not in ("provider", "bridge")}
    port = BridgePort(counter, parse_agent_config(agent))  # type: ignore[arg-type]  # only these two
    asyncio.run(port.setup())
    return counter.requests


# --- the probe ---------------------------------------------------------------------------------


class GraphProbe:
    """The microphone side (prompt_voice, prompt_text, voice_activity) and every output, recorded.
    Spins on its own thread; lists are appended there and read here."""

    def __init__(self, probe: Probe) -> None:
        self.probe = probe
        node = probe.node
        self._subscriptions: list[Any] = []
        self.listeners_needed: dict[str, int] = {}  # full topic → matched subscribers at the bridge
        self.voice = node.create_publisher(AudioDataUtterance, "prompt_voice", RELIABLE)
        self.text = node.create_publisher(String, "prompt_text", RELIABLE)
        self.activity = node.create_publisher(Bool, "voice_activity", RELIABLE)
        self.safety_stop = node.create_publisher(SafetyStop, "safety_stop", RELIABLE)  # as the VAD's spotter
        self.transcripts: list[String] = self._listen(String, "prompt_transcript")
        self.replies: list[String] = self._listen(String, "response_text")
        self.commands: list[String] = self._listen(String, "response_cmd")
        self.requests: list[CommandRequest] = self._listen(CommandRequest, "command_request")
        self.verdicts: list[CommandVerdict] = self._listen(CommandVerdict, "command_status")
        self.interruptions: list[Interruption] = self._listen(Interruption, "interruption_signal")
        # Deep: the player reports every block, and a test thread busy on a loaded machine can leave
        # this reader untaken for seconds; a 100-deep history then loses the one `finished` status.
        self.playback: list[PlaybackStatus] = self._listen(PlaybackStatus, "playback_status", DEEP)
        self.metrics: list[String] = self._listen(String, "agent_metrics")
        self.arm: list[String] = self._listen(String, "arm_preset")
        self.speaking: list[Bool] = self._listen(Bool, "assistant_speaking", LATCHED)
        self.diagnostics: list[DiagnosticArray] = self._listen(DiagnosticArray, "/diagnostics")
        self._utterances = 0

    def _listen(self, msg_type: Any, topic: str, qos: Any = RELIABLE) -> list[Any]:
        store: list[Any] = []
        self._subscriptions.append(self.probe.node.create_subscription(msg_type, topic, store.append, qos))
        return store

    def connected_to_bridge(self) -> bool:
        """Our prompts reach the bridge and the bridge's publishers reach us (DDS matched both ways)."""
        inputs = (self.voice, self.text, self.activity)
        outputs = [sub for sub in self._subscriptions if sub.topic_name.rsplit("/", 1)[-1] in BRIDGE_OUTPUTS]
        return all(pub.get_subscription_count() > 0 for pub in inputs) and all(
            sub.get_publisher_count() > 0 for sub in outputs
        )

    def texts(self, messages: list[Any]) -> list[str]:
        return [message.data for message in list(messages)]

    def metric_records(self) -> list[dict[str, Any]]:
        return [json.loads(message.data) for message in list(self.metrics)]

    def utterance(self, pcm: np.ndarray, chunk_ms: int = 100) -> list[AudioDataUtterance]:
        """One utterance's chunks as the VAD publishes them, the last one carrying the end marker."""
        self._utterances += 1
        utterance_id = 1_700_000_000_000_000_000 + self._utterances
        step = VAD_RATE * chunk_ms // 1000
        pieces = [pcm[k : k + step] for k in range(0, len(pcm), step)] or [pcm]
        return [
            AudioDataUtterance(
                int16_data=piece.astype(np.int16).tolist(),
                utterance_id=utterance_id,
                chunk_sequence=sequence,
                sample_rate=VAD_RATE,
                channels=1,
                is_utterance_end=sequence == len(pieces) - 1,
            )
            for sequence, piece in enumerate(pieces)
        ]

    def say(self, pcm: np.ndarray, chunk_ms: int = 100) -> None:
        """One utterance as the VAD publishes it: chunks, the last one carrying the end marker."""
        for message in self.utterance(pcm, chunk_ms):
            self.voice.publish(message)

    def type_text(self, text: str) -> None:
        self.text.publish(String(data=text))

    def wait_nodes(
        self,
        check: Callable[[], None],
        player: bool = False,
        processor: bool = False,
        forwarder: bool = False,
    ) -> None:
        """Until the player / command processor / frame forwarder are in the graph. Start them before
        the bridge and wait here: the bridge then matches them while it starts, so an agent's first
        command or reply is not lost to DDS discovery (nothing in ROS queues for a subscriber not
        yet matched)."""
        node = self.probe.node
        topic = self.probe.topic
        # wait_agents_ready then also waits until the bridge's publishers have matched these nodes
        if player:
            self.listeners_needed[topic("response_voice")] = 1
        if processor:
            self.listeners_needed[topic("response_cmd")] = 2  # the processor and this probe
            self.listeners_needed[topic("command_request")] = 1  # tool calls' commands

        def up() -> bool:
            check()
            player_up = not player or (
                bool(self.speaking) and node.count_subscribers(topic("response_voice")) > 0
            )
            processor_up = not processor or (
                node.count_subscribers(topic("response_cmd")) > 1
                and node.count_subscribers(topic("command_request")) > 0
                and node.count_publishers(topic("command_status")) > 0
            )
            forwarder_up = not forwarder or (
                node.count_subscribers(topic("camera/image_raw")) > 0
                and node.count_publishers(topic("camera_forwarded")) > 0
                and node.count_subscribers(topic("voice_activity")) > 0
            )
            return player_up and processor_up and forwarder_up

        wait_for(up, timeout=60, what="the player / command processor / frame forwarder in the graph")

    def bridge_values(self, namespace: str) -> dict[str, str] | None:
        for array in reversed(list(self.diagnostics)):
            for status in array.status:
                if status.name.startswith(namespace):
                    return {kv.key: kv.value for kv in status.values}
        return None

    def bridge_sources(self, namespace: str, name: str) -> int:
        """Publishers the bridge's own subscription to `name` has matched (its side of discovery)."""
        values = self.bridge_values(namespace) or {}
        return int(values.get(f"sources.{self.probe.topic(name)}", 0))

    def bridge_hears(self, publisher: Any, namespace: str, name: str) -> bool:
        """Both sides of the match between our `publisher` and the bridge's subscription to `name`:
        a best-effort subscription loses what is sent before it has matched, without a retry."""
        return publisher.get_subscription_count() > 0 and self.bridge_sources(namespace, name) > 0

    def wait_agents_ready(self, namespace: str, requests: list[int], timeout: float = 40.0) -> None:
        """Until the bridge has one client per agent and each has sent all its setup requests
        (subscriptions made: a prompt published now reaches the agent). Fails at once when an agent
        started since the last call has exited."""

        def ready() -> bool:
            _check_starting_agents()
            values = self.bridge_values(namespace)
            if values is None or values.get("clients") != str(len(requests)):
                return False
            seen = sorted(int(v) for k, v in values.items() if k.endswith(".received"))
            return all(have >= need for have, need in zip(seen, sorted(requests), strict=True))

        wait_for(ready, timeout=timeout, what=f"{len(requests)} agent(s) subscribed at the bridge")
        _STARTING.clear()  # all subscribed: what happens to them now is the test's business

        def matched() -> bool:
            values = self.bridge_values(namespace) or {}
            return all(int(values.get(f"listeners.{t}", 0)) >= n for t, n in self.listeners_needed.items())

        # The bridge's publishers see the player and processor (a first reply or command is not
        # lost to DDS discovery, which can take seconds on a loaded machine).
        wait_for(matched, timeout=timeout, what=f"the bridge's publishers matched {self.listeners_needed}")
        wait_for(self.connected_to_bridge, timeout=timeout, what="the probe matched with the bridge")
        assert self.bridge_values(namespace) is not None
        assert all(
            v == "0" for k, v in (self.bridge_values(namespace) or {}).items() if k.endswith(".rejected")
        ), "the bridge refused some of the agent's requests"


@contextmanager
def graph_probe(namespace: str) -> Iterator[GraphProbe]:
    with probe_node(namespace, "agent_probe") as probe:
        graph = GraphProbe(probe)
        thread = threading.Thread(target=probe.executor.spin, daemon=True)
        thread.start()
        try:
            yield graph
        finally:
            probe.executor.shutdown()
            thread.join(timeout=5)


def alive(*processes: subprocess.Popen[str]) -> Callable[[], None]:
    """A check for wait loops: fail at once (with the output) when a process under test died."""

    def check() -> None:
        for process in processes:
            assert process.poll() is None, f"{process.args!r} exited with {process.returncode}"

    return check


def until(condition: Callable[[], Any], what: str, check: Callable[[], None], timeout: float = 30.0) -> Any:
    def poll() -> Any:
        check()
        return condition()

    return wait_for(poll, timeout=timeout, interval=0.02, what=what)


# --- a Gemini agent graph ----------------------------------------------------------------------


@dataclass
class RunningAgent:
    process: subprocess.Popen[str]
    output: Output
    settings: dict[str, Any]

    def stop(self) -> list[str]:
        return stop_agent(self.process, self.output)


def stop_agent(process: subprocess.Popen[str], output: Output) -> list[str]:
    """SIGTERM, as Ctrl-C or `ros2 launch` would: the agent closes its session and exits 0. Its log
    lines, none of which holds the API key."""
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=30) == 0, str(output)
    lines = output.finish()
    assert FAKE_KEY not in "\n".join(lines), "the API key reached a log line"
    return lines


def stop_player(player: subprocess.Popen[str]) -> None:
    """SIGTERM: the WAV sink writes what had sounded and closes the file."""
    player.send_signal(signal.SIGTERM)
    player.wait(timeout=30)


@dataclass
class AgentGraph:
    probe: GraphProbe
    agents: list[RunningAgent]
    check: Callable[[], None]  # fails at once when any process of the graph died


@contextmanager
def gemini_graph(
    namespace: str,
    tmp_path: Path,
    agents: Sequence[tuple[GeminiEmulatorThread, str, dict[str, Any]]],
    wav: Path | None = None,
    processor: bool = False,
    forwarder: Sequence[str] | None = None,
    installed: bool = False,
    bridge_params: Sequence[str] = (),
) -> Iterator[AgentGraph]:
    """The probe, the nodes asked for (player with a WAV sink, command processor, frame forwarder
    with `forwarder` parameters), the bridge, and one `byc agent` per (emulator, shipped config,
    settings), each subscribed at the bridge. `installed`: each agent is instead the installed
    executable of its shipped config (GEMINI_EXECUTABLES, `installed_gemini_agent`; no settings)."""
    with ExitStack() as stack:
        probe = stack.enter_context(graph_probe(namespace))
        nodes: list[subprocess.Popen[str]] = []
        if wav is not None:
            nodes.append(stack.enter_context(player_process(namespace, wav)))
        if processor:
            nodes.append(stack.enter_context(processor_process(namespace)))
        if forwarder is not None:
            nodes.append(stack.enter_context(frame_forwarder_process(namespace, *forwarder)))
        probe.wait_nodes(alive(*nodes), wav is not None, processor, forwarder is not None)
        port, _ = stack.enter_context(bridge_process(namespace, 0, *bridge_params))
        running = []
        for api, shipped, settings in agents:
            if installed:
                assert not settings, "an installed agent runs its shipped config (pointed at the emulator)"
                data = yaml.safe_load((CONFIG_DIR / shipped).read_text())
                process, output = stack.enter_context(
                    installed_gemini_agent(GEMINI_EXECUTABLES[shipped], api, port)
                )
            else:
                config, data = gemini_agent_config(tmp_path, api, shipped, **settings)
                process, output = stack.enter_context(agent_process(config, port))
            running.append(RunningAgent(process, output, data))
        check = alive(*(agent.process for agent in running), *nodes)
        probe.wait_agents_ready(namespace, [setup_requests(agent.settings) for agent in running], 60.0)
        yield AgentGraph(probe, running, check)
