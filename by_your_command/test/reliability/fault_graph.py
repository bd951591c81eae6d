"""Helpers for the fault injection suite (test_faults.py) and bench/bench_faults.py: the real VAD
node fed by the probe's audio, a raw WebSocket client that never reads, and the ledger every fault
test closes with (each utterance answered or reported). The killable bridge is agent_graph's."""

from __future__ import annotations

import base64
import os
import re
import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from agent_graph import VAD_RATE, GraphProbe, Output
from by_your_command_msgs.msg import AudioChunk
from byc_testing import python_module, running_process

from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import STREAM

LOST_BY_VAD = " lost: "  # "is lost": nobody subscribed to prompt_voice; "may be lost": nobody acknowledged


# --- the real VAD, fed by the probe -------------------------------------------------------------


class Microphone:
    """silero_vad_node as a process, fed 32 ms AudioChunks on `audio` by the probe's node: the
    real VAD decides the utterances, publishes prompt_voice, and reports the ones nobody hears."""

    def __init__(self, probe: GraphProbe, process: subprocess.Popen[str]) -> None:
        self.process = process
        self.output = Output(process)
        self.audio = probe.probe.node.create_publisher(AudioChunk, "audio", STREAM)

    def ready(self) -> bool:
        return self.audio.get_subscription_count() > 0

    def unheard(self) -> list[str]:
        return [line for line in list(self.output.lines) if LOST_BY_VAD in line]

    def mark(self) -> int:
        return len(self.output.lines)

    def gained_listener(self, since: int) -> bool:
        """The VAD's own publisher matched another prompt_voice subscriber after `since` (mark())."""
        for line in list(self.output.lines)[since:]:
            counts = re.search(r"prompt_voice subscribers: (\d+) -> (\d+)", line)
            if counts and int(counts[2]) > int(counts[1]):
                return True
        return False

    def speak(self, speech: np.ndarray, speed: float = 4.0) -> None:
        """Half a second of silence, the speech, then a second of silence (its end): paced at
        `speed` times real time, so the best-effort audio topic keeps every block."""
        silence = np.zeros(VAD_RATE // 2, np.int16)
        pcm = np.concatenate([silence, speech, silence, silence])
        start = time.monotonic()
        for index, offset in enumerate(range(0, len(pcm), 512)):
            self.audio.publish(make_audio_chunk(pcm[offset : offset + 512], VAD_RATE, 1))
            due = start + (index + 1) * 512 / VAD_RATE / speed
            time.sleep(max(0.0, due - time.monotonic()))  # pacing a stream, not waiting on anything


@contextmanager
def microphone(namespace: str, probe: GraphProbe) -> Iterator[Microphone]:
    command = python_module(
        "by_your_command.nodes.silero_vad_node", "--ros-args", "-r", f"__ns:={namespace}",
        "-p", "input_topic:=audio",
    )  # fmt: skip
    with running_process(command) as process:
        yield Microphone(probe, process)


# --- a client that stops reading ----------------------------------------------------------------


class DeafClient:
    """A raw WebSocket client (a plain socket with a 4 KiB receive buffer): it subscribes to
    `topics`, then never reads another byte."""

    def __init__(self, port: int, topics: tuple[str, ...]) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        self.sock.connect(("127.0.0.1", port))
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
            ).encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            data = self.sock.recv(1)
            assert data, "the bridge closed the handshake"
            head += data
        assert head.startswith(b"HTTP/1.1 101"), head
        for topic in topics:
            self._send_text(f'{{"op":"subscribe","topic":"{topic}"}}')

    def _send_text(self, text: str) -> None:
        payload = text.encode()
        assert len(payload) < 126
        mask = os.urandom(4)
        masked = bytes(byte ^ mask[i % 4] for i, byte in enumerate(payload))
        self.sock.sendall(bytes([0x81, 0x80 | len(payload)]) + mask + masked)

    def close(self) -> None:
        self.sock.close()


# --- the ledger ---------------------------------------------------------------------------------


@dataclass
class Ledger:
    """Every user utterance a fault test made, and its fate: answered, or reported (by whom)."""

    asked: list[str] = field(default_factory=list)
    fates: dict[str, str] = field(default_factory=dict)

    def ask(self, label: str) -> str:
        self.asked.append(label)
        return label

    def answered(self, label: str) -> None:
        self._settle(label, "answered")

    def reported(self, label: str, by: str) -> None:
        self._settle(label, f"reported: {by}")

    def _settle(self, label: str, fate: str) -> None:
        assert label in self.asked and label not in self.fates, (label, self.fates)
        self.fates[label] = fate

    def check(self) -> dict[str, Any]:
        """0 silent losses: every utterance asked was answered or reported."""
        silent = [label for label in self.asked if label not in self.fates]
        assert not silent, f"utterances neither answered nor reported: {silent}"
        return dict(self.fates)


def turn_records(probe: GraphProbe) -> list[dict[str, Any]]:
    return [r for r in probe.metric_records() if r["record"] == "turn"]


def failures(probe: GraphProbe) -> list[str]:
    """The agent's failed-turn reports: its turn records' reasons (`turn N failed: why`)."""
    return [
        f"turn {r['turn']} {r['outcome']}: {r['reason']}"
        for r in turn_records(probe)
        if r["outcome"] in ("failed", "undelivered")
    ]
