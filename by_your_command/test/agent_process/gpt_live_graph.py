"""Helpers for the GPT-Live graph tests: the GPT-Live emulator (`byc emulate gpt-live`'s server) on
its own event-loop thread, and a graph of real nodes (player with a WAV sink, command processor,
demo_robot, ros_ai_bridge with the robot's tools) with `byc agent --config agent_gpt_live.yaml`
pointed at it."""

from __future__ import annotations

import base64
import re
import subprocess
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from agent_graph import (
    FAKE_KEY,
    GraphProbe,
    Output,
    agent_process,
    alive,
    bridge_process,
    demo_robot,
    graph_probe,
    player_process,
    processor_process,
    setup_requests,
    shipped_agent_config,
    stop_agent,
    stop_player,
    until,
)
from std_msgs.msg import Bool

from by_your_command.audio.pcm import StreamResampler
from by_your_command.emulators import gpt_live
from by_your_command.emulators.gpt_live_script import Script
from by_your_command.emulators.threaded import ThreadedEmulator


class GptLiveEmulatorThread(ThreadedEmulator[gpt_live.GptLiveEmulator]):
    """`emulators.gpt_live` served from a private loop; every read hops onto that loop."""

    def __init__(self, script: Script) -> None:
        super().__init__(gpt_live.start(script=script))
        self.url = self.handle.websocket_base_url

    def received(self, connection: int | None = None) -> list[dict[str, Any]]:
        records = self._read(lambda: list(self.handle.received))
        return [r.event for r in records if connection is None or r.connection == connection]

    def types(self, connection: int | None = None) -> list[str]:
        return [str(event["type"]) for event in self.received(connection)]

    def session_start(self, connection: int) -> dict[str, Any]:
        [start] = [e["session"] for e in self.received(connection) if e["type"] == "session.start"]
        return dict(start)

    def appended(self, connection: int) -> bytes:
        """The PCM the client appended to the session's input stream, in order."""
        events = self.received(connection)
        return b"".join(
            base64.b64decode(e["audio"]) for e in events if e["type"] == "session.input_audio.append"
        )

    def connections(self) -> int:
        return self._read(lambda: len(self.handle.handshakes))

    def interruptions(self) -> list[gpt_live.Interruption]:
        """Replies the emulator stopped because the user spoke over them (the model yielding)."""
        return self._read(lambda: list(self.handle.interruptions))

    def delegation_ids(self) -> list[str]:
        """Every `session.delegation.created` the emulator sent, in order."""
        return self._read(lambda: [d.delegation_id for d in self.handle.delegations])

    def commentaries(self) -> list[dict[str, Any]]:
        """Every `session.commentary.append` the client sent (a delegation's result)."""
        return [e for e in self.received() if e["type"] == "session.commentary.append"]

    def open_connections(self) -> int:
        return self._read(lambda: self.handle.open_connections)

    def refused_handshakes(self) -> int:
        return self._read(lambda: self.handle.refused_handshakes)


def at_24k(pcm: np.ndarray) -> bytes:
    """A 16 kHz utterance as the agent sends it: resampled to the session's 24 kHz."""
    resampler = StreamResampler(16000, 24000)
    return np.concatenate([resampler.push(pcm), resampler.flush()]).astype("<i2").tobytes()


def gpt_live_agent_config(
    tmp_path: Path, api: GptLiveEmulatorThread, **settings: Any
) -> tuple[Path, dict[str, Any]]:
    """The shipped agent_gpt_live.yaml pointed at the emulator, with the echo-cancelled microphone
    (echo_mode aec, as the gpt_live profile runs it); `settings` override AgentConfig keys,
    `provider` is merged into the provider's."""
    endpoint = {"websocket_base_url": api.url}
    return shipped_agent_config(tmp_path, "agent_gpt_live.yaml", endpoint, **{"echo_mode": "aec", **settings})


def say_live(probe: GraphProbe, pcm: np.ndarray, chunk_ms: int = 100) -> None:
    """One utterance as the VAD publishes it live: voice_activity on, its chunks at real time (the
    model hears speech over its reply arrive as it is said, and yields part-way through it, as it
    would), voice_activity off."""
    probe.activity.publish(Bool(data=True))
    start = time.monotonic()
    for index, message in enumerate(probe.utterance(pcm, chunk_ms)):
        # Pacing a live source, not waiting for a condition: chunk k is published when said.
        time.sleep(max(0.0, start + index * chunk_ms / 1000 - time.monotonic()))
        probe.voice.publish(message)
    probe.activity.publish(Bool(data=False))


@dataclass
class LiveGraph:
    api: GptLiveEmulatorThread
    probe: GraphProbe
    agent: subprocess.Popen[str]
    agent_out: Output
    check: Any  # fails at once when a process of the graph died
    player: subprocess.Popen[str] | None
    robot_out: Output | None = None  # demo_robot's log, when it runs

    def stop_agent(self) -> list[str]:
        return stop_agent(self.agent, self.agent_out)

    def stop_player(self) -> None:
        assert self.player is not None
        stop_player(self.player)

    def records(self, kind: str) -> list[dict[str, Any]]:
        return [r for r in self.probe.metric_records() if r["record"] == kind]

    def finished_streams(self) -> list[str]:
        return [s.stream_id for s in list(self.probe.playback) if s.finished]

    def robot_goals(self) -> list[tuple[float, float, str]]:
        """The goals demo_robot was given: (x, y, frame), from its log."""
        assert self.robot_out is not None
        found = (
            re.search(r"driving to \((\S+), (\S+)\) in '(\w*)'", line) for line in list(self.robot_out.lines)
        )
        return [(float(m[1]), float(m[2]), m[3]) for m in found if m]


@contextmanager
def live_graph(
    namespace: str,
    tmp_path: Path,
    script: Script,
    wav: Path | None = None,
    processor: bool = False,
    key: str = FAKE_KEY,
    options: tuple[str, ...] = (),
    tools: Path | None = None,
    robot: tuple[str, ...] | None = None,
    **settings: Any,
) -> Iterator[LiveGraph]:
    """Emulator, probe, the nodes asked for, bridge, and `byc agent` on agent_gpt_live.yaml, ready.
    `tools`: the bridge's tools file (the agent holds those tools); `robot`: demo_robot runs, with
    these name:=value parameters."""
    with ExitStack() as stack:
        api = stack.enter_context(GptLiveEmulatorThread(script))
        probe = stack.enter_context(graph_probe(namespace))
        nodes: list[subprocess.Popen[str]] = []
        player = stack.enter_context(player_process(namespace, wav)) if wav is not None else None
        if player is not None:
            nodes.append(player)
        if processor:
            nodes.append(stack.enter_context(processor_process(namespace)))
        robot_out = None
        if robot is not None:
            robot_process, robot_out = stack.enter_context(demo_robot(namespace, *robot))
            nodes.append(robot_process)
        probe.wait_nodes(alive(*nodes), player is not None, processor)
        bridge_params = () if tools is None else (f"tools_path:={tools}",)
        port, _ = stack.enter_context(bridge_process(namespace, 0, *bridge_params))
        config, data = gpt_live_agent_config(tmp_path, api, **settings)
        agent, agent_out = stack.enter_context(agent_process(config, port, key, *options))
        check = alive(agent, *nodes)
        probe.wait_agents_ready(namespace, [setup_requests(data)], 60.0)
        if tools is not None:
            until(
                lambda: agent_out.find(r"the robot's tools: "), "the agent got the robot's tools", check, 60.0
            )
        yield LiveGraph(api, probe, agent, agent_out, check, player, robot_out)
