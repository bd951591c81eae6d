"""Shared by bench_agent_latency.py, bench_barge_in.py and bench_frame_age.py: the agent's real
graph as processes (ros_ai_bridge, simple_audio_player with a real-time WAV sink, optionally
frame_forwarder, `byc agent` with the OpenAI or the Gemini provider) against that provider's
emulator on a thread of this process (Gemini's over TLS with its own certificate, as the SDK
requires), a bench node standing in for the VAD and the camera, and the same-run baselines: a raw
DDS publish→subscribe of an utterance chunk between two DDS participants, and a raw WebSocket
round trip of that chunk as rosbridge JSON.

Discovery stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless set; run under
`unshare -n` for a private network, as scripts/run_tests.sh does), in a namespace of its own.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml

from by_your_command.agents.bridge_port import BridgePort
from by_your_command.agents.config import parse_agent_config
from by_your_command.bridge.client_messages import Delivery
from by_your_command.emulators import gemini_live, gpt_live
from by_your_command.emulators import gemini_script as gemini
from by_your_command.emulators import gpt_live_script as live
from by_your_command.emulators.gemini_wire import decode_blob, field_value
from by_your_command.emulators.openai_realtime import OpenAIRealtimeEmulator, start
from by_your_command.emulators.openai_script import Script
from by_your_command.emulators.threaded import ThreadedEmulator

T = TypeVar("T")
VAD_RATE = 16000
CHUNK_MS = 100
PROVIDERS = ("openai", "gemini", "gpt_live")


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else float("nan")


def wait_until(condition: Callable[[], T | None], timeout: float, what: str) -> T:
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(0.001)


# --- the emulator ------------------------------------------------------------------------------


class EmulatorThread(ThreadedEmulator[OpenAIRealtimeEmulator]):
    """The OpenAI Realtime emulator."""

    def __init__(self, script: Script) -> None:
        super().__init__(start(script=script))

    def provider_settings(self) -> dict[str, Any]:
        return {"type": "openai", "websocket_base_url": self.handle.websocket_base_url}

    def received_types(self) -> list[str]:
        return self._read(self.handle.received_types)

    def events(self, type_: str) -> list[dict[str, Any]]:
        """The client events of one type the emulator received, in order."""
        return self._read(lambda: [r.event for r in self.handle.received if r.event["type"] == type_])


class GeminiEmulatorThread(ThreadedEmulator[gemini_live.GeminiLiveEmulator]):
    """The Gemini Live emulator (TLS: the SDK only speaks wss)."""

    def __init__(self, script: gemini.Script) -> None:
        super().__init__(gemini_live.start(script=script))

    def provider_settings(self) -> dict[str, Any]:
        return {"type": "gemini", "base_url": self.handle.base_url, "ca_file": str(self.handle.cert_file)}

    def received_types(self) -> list[str]:
        """One name per part of what the client sent: setup, clientContent, toolResponse, and for
        realtimeInput each of activityStart, audio, video, text, activityEnd."""
        parts = ("activityStart", "audio", "video", "text", "activityEnd", "audioStreamEnd")
        out: list[str] = []
        for record in self._read(lambda: list(self.handle.received)):
            if record.kind == "realtimeInput":
                out += [part for part in parts if field_value(record.body, part) is not None]
            else:
                out.append(record.kind)
        return out

    def frames_received(self) -> int:
        return self._read(lambda: sum(1 for r in self.handle.received if _video(r.body) is not None))

    def frame(self, index: int) -> bytes:
        """The `index`th camera frame the client sent (JPEG)."""
        videos = self._read(lambda: [v for r in self.handle.received if (v := _video(r.body)) is not None])
        return decode_blob(field_value(videos[index], "data"), "video")


def _video(body: dict[str, Any]) -> dict[str, Any] | None:
    video = field_value(body, "video")
    return video if isinstance(video, dict) else None


class GptLiveEmulatorThread(ThreadedEmulator[gpt_live.GptLiveEmulator]):
    """The GPT-Live emulator."""

    def __init__(self, script: live.Script) -> None:
        super().__init__(gpt_live.start(script=script))

    def provider_settings(self) -> dict[str, Any]:
        return {"type": "gpt_live", "websocket_base_url": self.handle.websocket_base_url}

    def received_types(self) -> list[str]:
        return self._read(self.handle.received_types)


AnyScript = Script | gemini.Script | live.Script
AnyEmulator = EmulatorThread | GeminiEmulatorThread | GptLiveEmulatorThread


def emulator_for(provider: str, script: AnyScript) -> AnyEmulator:
    if provider == "gemini":
        assert isinstance(script, gemini.Script)
        return GeminiEmulatorThread(script)
    if provider == "gpt_live":
        assert isinstance(script, live.Script)
        return GptLiveEmulatorThread(script)
    assert isinstance(script, Script)
    return EmulatorThread(script)


# --- processes ---------------------------------------------------------------------------------


class Process:
    """A child process with its merged output collected on a thread."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None) -> None:
        self.popen = subprocess.Popen(
            args,
            env={**os.environ, **(env or {})},
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        self.lines: list[str] = []
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self.lines.append(line.rstrip("\n"))

    def find(self, pattern: str) -> re.Match[str] | None:
        return next((m for line in list(self.lines) if (m := re.search(pattern, line))), None)

    def check(self) -> None:
        if self.popen.poll() is not None:
            tail = "\n".join(self.lines[-30:])
            raise RuntimeError(f"{self.popen.args!r} exited with {self.popen.returncode}:\n{tail}")

    def stop(self) -> None:
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGTERM)
            try:
                self.popen.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(self.popen.pid, signal.SIGKILL)
                self.popen.wait()
        self._keep_output()

    def _keep_output(self) -> None:
        """With BENCH_PROCESS_LOGS=DIR, the process's output goes to DIR (to see why a trial failed)."""
        folder = os.environ.get("BENCH_PROCESS_LOGS")
        if not folder:
            return
        args = [str(a) for a in self.popen.args]  # type: ignore[union-attr]
        name = next((a.rsplit(".", 1)[-1] for a in args if a.startswith("by_your_command.")), "process")
        Path(folder).mkdir(parents=True, exist_ok=True)
        Path(folder, f"{name}-{self.popen.pid}.log").write_text("\n".join(self.lines) + "\n")


def node_command(module: str, namespace: str, *params: str) -> list[str]:
    args = [sys.executable, "-m", f"by_your_command.nodes.{module}", "--ros-args", "-r", f"__ns:={namespace}"]
    for param in params:
        args += ["-p", param]
    return args


def setup_requests(settings: dict[str, Any]) -> int:
    """Subscribe + advertise requests an agent with these settings sends the bridge at connect."""

    class Counter:
        requests = 0

        async def subscribe(self, topic: str, msg_type: str | None = None) -> None:
            self.requests += 1

        async def advertise(self, topic: str, msg_type: str) -> None:
            self.requests += 1

        async def publish(self, topic: str, msg: dict[str, Any]) -> None:
            raise NotImplementedError

        async def receive(self, timeout: float | None = None) -> Delivery:
            raise NotImplementedError

        async def call_service(
            self,
            service: str,
            args: dict[str, Any],
            request_id: str,
            service_type: str | None = None,
            timeout_s: float | None = None,
        ) -> None:
            raise NotImplementedError

        async def send_action_goal(
            self, action: str, action_type: str, args: dict[str, Any], request_id: str
        ) -> None:
            raise NotImplementedError

        async def cancel_action_goal(self, action: str, request_id: str) -> None:
            raise NotImplementedError

    counter = Counter()
    agent = {key: value for key, value in settings.items() if key not in ("provider", "bridge")}
    asyncio.run(BridgePort(counter, parse_agent_config(agent)).setup())
    return counter.requests


# --- the bench node ----------------------------------------------------------------------------


@dataclass
class Stamped:
    at: float  # time.monotonic() when the callback ran
    msg: Any


@dataclass
class BenchNode:
    """The VAD's side (prompt_voice, voice_activity, prompt_text) and the player's reports,
    each message stamped on arrival."""

    namespace: str
    statuses: list[Stamped] = field(default_factory=list)
    played: list[Stamped] = field(default_factory=list)
    metrics: list[Stamped] = field(default_factory=list)
    diagnostics: list[Any] = field(default_factory=list)
    speaking: list[Any] = field(default_factory=list)
    activity_heard: list[Stamped] = field(default_factory=list)  # voice_activity, whoever published it
    interruptions: list[Stamped] = field(default_factory=list)  # interruption_signal (cut, pause, resume)

    def __post_init__(self) -> None:
        import rclpy
        from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance, Interruption, PlaybackStatus
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from std_msgs.msg import Bool, String

        from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

        self._utterance_type, self._bool, self._string = AudioDataUtterance, Bool, String
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node("bench_agent", namespace=self.namespace, context=self.context)
        node = self.node
        self.voice = node.create_publisher(AudioDataUtterance, "prompt_voice", RELIABLE)
        self.activity = node.create_publisher(Bool, "voice_activity", RELIABLE)
        self.text = node.create_publisher(String, "prompt_text", RELIABLE)
        stamp = self._stamper
        node.create_subscription(PlaybackStatus, "playback_status", stamp(self.statuses), RELIABLE)
        node.create_subscription(AudioChunk, "audio_played", stamp(self.played), STREAM)
        node.create_subscription(String, "agent_metrics", stamp(self.metrics), RELIABLE)
        node.create_subscription(Bool, "assistant_speaking", self.speaking.append, LATCHED)
        node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, RELIABLE)
        node.create_subscription(Bool, "voice_activity", stamp(self.activity_heard), RELIABLE)
        node.create_subscription(Interruption, "interruption_signal", stamp(self.interruptions), RELIABLE)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(node)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()
        self._utterances = 0

    @staticmethod
    def _stamper(store: list[Stamped]) -> Callable[[Any], None]:
        def on_message(msg: Any) -> None:
            store.append(Stamped(time.monotonic(), msg))

        return on_message

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self._thread.join(timeout=5)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def topic(self, name: str) -> str:
        return f"{self.namespace}/{name}"

    def chunk(self, pcm: np.ndarray, utterance_id: int, sequence: int, end: bool) -> Any:
        return self._utterance_type(
            int16_data=pcm.astype(np.int16).tolist(),
            utterance_id=utterance_id,
            chunk_sequence=sequence,
            sample_rate=VAD_RATE,
            channels=1,
            is_utterance_end=end,
        )

    def new_utterance(self) -> int:
        self._utterances += 1
        return 1_700_000_000_000_000_000 + self._utterances

    def say_activity(self, active: bool) -> None:
        self.activity.publish(self._bool(data=active))

    def type_text(self, text: str) -> None:
        self.text.publish(self._string(data=text))

    def bridge_values(self) -> dict[str, str] | None:
        for array in reversed(list(self.diagnostics)):
            for status in array.status:
                if status.name.startswith(self.namespace):
                    return {kv.key: kv.value for kv in status.values}
        return None

    def agent_ready(self, requests: int) -> bool:
        values = self.bridge_values()
        if values is None or values.get("clients") != "1":
            return False
        received = [int(v) for k, v in values.items() if k.endswith(".received")]
        matched = all(p.get_subscription_count() > 0 for p in (self.voice, self.activity, self.text))
        # The bridge's side of its match with the player: a reply published before it is lost to
        # DDS discovery (seen on a loaded machine: the first turn timed out, 1 run in 3).
        played = int(values.get(f"listeners.{self.topic('response_voice')}", "0")) >= 1
        return bool(received) and received[0] >= requests and matched and played

    def statuses_of(self, stream_id: str) -> list[Stamped]:
        return [s for s in list(self.statuses) if s.msg.stream_id == stream_id]

    def new_stream(self, known: set[str]) -> Stamped | None:
        """The first status of a stream not in `known` that reports it speaking."""
        return next(
            (
                s
                for s in list(self.statuses)
                if s.msg.stream_id and s.msg.stream_id not in known and s.msg.speaking
            ),
            None,
        )


@dataclass(frozen=True)
class ExtraNode:
    """A node of the package started before the bridge (the VAD, echo control), ready once a line
    of its output matches `ready`."""

    module: str  # by_your_command.nodes.<module>
    params: tuple[str, ...] = ()  # name:=value
    ready: str = ""  # a regular expression; "" = ready once started


@dataclass
class AgentGraph:
    bench: BenchNode
    emulator: AnyEmulator
    processes: list[Process]
    wav: Path | None = None  # what the player played (its header is written when it stops)

    def check(self) -> None:
        for process in self.processes:
            process.check()


@contextmanager
def agent_graph(
    script: AnyScript,
    label: str,
    provider: str = "openai",
    forwarder: tuple[str, ...] | None = None,
    nodes: tuple[ExtraNode, ...] = (),
    **settings: Any,
) -> Iterator[AgentGraph]:
    """Player (and frame_forwarder with `forwarder` parameters, and `nodes`), bridge and agent
    processes in a fresh namespace, the `provider`'s emulator, the bench node."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    namespace = f"/bench_{label}_{provider}_{os.getpid()}"
    with ExitStack() as stack:
        tmp = Path(stack.enter_context(tempfile.TemporaryDirectory()))
        emulator = emulator_for(provider, script)
        stack.callback(emulator.stop)
        bench = BenchNode(namespace)
        stack.callback(bench.close)
        processes: list[Process] = []

        def started(process: Process) -> Process:
            processes.append(process)
            stack.callback(process.stop)
            return process

        player = started(
            Process(
                node_command(
                    "simple_audio_player",
                    namespace,
                    "sink:=wav",
                    f"wav_path:={tmp / 'played.wav'}",
                    "sample_rate:=24000",
                    "realtime:=true",
                )  # fmt: skip
            )
        )

        def player_up() -> bool:
            player.check()
            return bool(bench.speaking) and bench.node.count_subscribers(bench.topic("response_voice")) > 0

        wait_until(player_up, 60, "the player")
        if forwarder is not None:
            camera_node = started(Process(node_command("frame_forwarder", namespace, *forwarder)))

            def forwarder_up() -> bool:
                camera_node.check()
                node = bench.node
                subscribed: int = node.count_subscribers(bench.topic("camera/image_raw"))
                publishing: int = node.count_publishers(bench.topic("camera_forwarded"))
                return subscribed > 0 and publishing > 0

            wait_until(forwarder_up, 60, "the frame forwarder")
        for extra in nodes:
            process = started(Process(node_command(extra.module, namespace, *extra.params)))

            def extra_up(process: Process = process, pattern: str = extra.ready) -> bool:
                process.check()
                return not pattern or process.find(pattern) is not None

            wait_until(extra_up, 120, extra.module)
        bridge = started(
            Process(node_command("ros_ai_bridge", namespace, "port:=0", "diagnostics_period_s:=0.2"))
        )

        def bridge_port() -> re.Match[str] | None:
            bridge.check()
            return bridge.find(r"listening on 127\.0\.0\.1:(\d+)")

        match = wait_until(bridge_port, 60, "the bridge")
        data = {
            "agent_id": "bench",
            "pause_timeout_s": 600.0,
            "conversation_timeout_s": 3600.0,
            **settings,
            "provider": emulator.provider_settings(),
        }
        config = tmp / "agent.yaml"
        config.write_text(yaml.safe_dump(data))
        started(
            Process(
                [sys.executable, "-m", "by_your_command.cli.byc", "agent", "--config", str(config)],
                {
                    "OPENAI_API_KEY": "sk-bench-not-a-key",
                    "GEMINI_API_KEY": "bench-not-a-key",
                    "BYC_BRIDGE_URL": f"ws://127.0.0.1:{match.group(1)}",
                },
            )
        )
        graph = AgentGraph(bench, emulator, processes, tmp / "played.wav")
        requests = setup_requests(data)

        def agent_ready() -> bool:
            graph.check()
            return bench.agent_ready(requests)

        wait_until(agent_ready, 60, "the agent subscribed")
        yield graph


# --- baselines ---------------------------------------------------------------------------------


def dds_one_way_ms(trials: int, chunk: np.ndarray) -> list[float]:
    """A raw DDS publish→subscribe of one utterance chunk (as on prompt_voice)."""
    from by_your_command_msgs.msg import AudioDataUtterance

    msg = AudioDataUtterance(int16_data=chunk.astype(np.int16).tolist(), sample_rate=VAD_RATE, channels=1)
    return dds_message_one_way_ms(trials, msg)


def dds_message_one_way_ms(trials: int, msg: Any) -> list[float]:
    """A raw DDS publish→subscribe of the ROS message `msg` between two participants of this
    process (each its own context), reliable QoS: publish call → subscriber callback."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from by_your_command.nodes._qos import RELIABLE

    contexts = [rclpy.Context(), rclpy.Context()]
    for context in contexts:
        rclpy.init(context=context)
    namespace = f"/bench_dds_{os.getpid()}_{id(contexts)}"
    sender = Node("dds_sender", namespace=namespace, context=contexts[0])
    receiver = Node("dds_receiver", namespace=namespace, context=contexts[1])
    arrived: list[float] = []
    got = threading.Event()

    def on_message(_: Any) -> None:
        arrived.append(time.monotonic())
        got.set()

    receiver.create_subscription(type(msg), "message", on_message, RELIABLE)
    publisher = sender.create_publisher(type(msg), "message", RELIABLE)
    executor = SingleThreadedExecutor(context=contexts[1])
    executor.add_node(receiver)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    latencies: list[float] = []
    try:
        wait_until(lambda: publisher.get_subscription_count() > 0, 30, "DDS discovery")
        for index in range(trials + 3):
            got.clear()
            time.sleep(0.01)
            sent = time.monotonic()
            publisher.publish(msg)
            if got.wait(5) and index >= 3:  # the first few warm up the path
                latencies.append(1000 * (arrived[-1] - sent))
    finally:
        executor.shutdown()
        thread.join(timeout=5)
        sender.destroy_node()
        receiver.destroy_node()
        for context in contexts:
            rclpy.try_shutdown(context=context)
    return latencies


def websocket_round_trip_ms(trials: int, chunk: np.ndarray) -> list[float]:
    """A raw WebSocket round trip (echo server on a thread, sync client) of the chunk as the
    rosbridge JSON the bridge sends (an `op: publish` of the AudioDataUtterance)."""
    from websockets.asyncio.server import ServerConnection, serve
    from websockets.sync.client import connect

    frame = json.dumps(
        {"op": "publish", "topic": "prompt_voice", "msg": {"int16_data": chunk.astype(int).tolist()}}
    )
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()

    async def echo(connection: ServerConnection) -> None:
        async for message in connection:
            await connection.send(message)

    async def serve_echo() -> Any:
        return await serve(echo, "127.0.0.1", 0, compression=None)

    server = asyncio.run_coroutine_threadsafe(serve_echo(), loop).result(10)
    port = server.sockets[0].getsockname()[1]
    latencies: list[float] = []
    try:
        with connect(f"ws://127.0.0.1:{port}", compression=None) as client:
            for index in range(trials + 3):
                time.sleep(0.01)
                sent = time.monotonic()
                client.send(frame)
                client.recv(timeout=5)
                if index >= 3:
                    latencies.append(1000 * (time.monotonic() - sent))
    finally:

        async def close() -> None:
            server.close()
            await server.wait_closed()

        asyncio.run_coroutine_threadsafe(close(), loop).result(10)
        loop.call_soon_threadsafe(loop.stop)
        thread.join(timeout=5)
    return latencies


def summary(values: list[float]) -> dict[str, float]:
    return {
        "n": len(values),
        "p50": round(percentile(values, 50), 2),
        "p95": round(percentile(values, 95), 2),
        "max": round(max(values), 2) if values else float("nan"),
    }


def table(rows: list[tuple[str, list[float], str]]) -> None:
    print()
    print(f"{'figure':48s} {'n':>4s} {'p50 ms':>8s} {'p95 ms':>8s}  note")
    for name, values, note in rows:
        print(
            f"{name:48s} {len(values):4d} {percentile(values, 50):8.2f} {percentile(values, 95):8.2f}  {note}"
        )
