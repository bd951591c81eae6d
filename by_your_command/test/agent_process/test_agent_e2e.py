"""End to end (issue 9): a WAV file of the speech corpus → file_audio_publisher → echo_suppressor
(gate) → silero_vad_node → ros_ai_bridge → `byc agent` (OpenAI provider, tool mode) → the OpenAI
emulator, and back: the spoken replies into simple_audio_player (WAV sink), the robot_command tool
call through command_processor. Every node is its own process on a real DDS graph; the only
stand-in is the emulator for the cloud."""

from __future__ import annotations

import base64
import json
import signal
import subprocess
import threading
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np
import pytest
from agent_graph import (
    CORPUS,
    FAKE_KEY,
    VAD_RATE,
    GraphProbe,
    Output,
    agent_config,
    agent_process,
    alive,
    bridge_process,
    corpus_utterance,
    emulator,
    player_process,
    processor_process,
    setup_requests,
    until,
)
from by_your_command_msgs.msg import AudioDataUtterance
from byc_testing import python_module, running_process
from ros_probe import probe_node
from std_msgs.msg import String

from by_your_command.audio.pcm import StreamResampler, read_wav, write_wav
from by_your_command.emulators.openai_script import CallTool, Say, Script, Turn
from by_your_command.emulators.synthetic_speech import speech_pcm
from by_your_command.nodes._qos import LATCHED, RELIABLE

pytestmark = [pytest.mark.ros, pytest.mark.e2e, pytest.mark.timeout(180)]

MS_PER_CHAR = 40
GAP_S = 2.0  # between utterances: the reply plays and the gate's tail passes before the next one
SPOKEN = ("Hello robot, what do you see?", "Turn left and look at the door.")  # corpus segments 0, 1


def corpus_file(path: Path) -> Path:
    """Two utterances of the committed corpus (clean_en_us, segments 0 and 1), GAP_S of room
    silence apart and after: the microphone recording the file publisher plays."""
    segments = json.loads((CORPUS / "segments.json").read_text())["sessions"]["clean_en_us"]["segments"]
    assert tuple(segment["text"] for segment in segments[:2]) == SPOKEN
    gap = np.zeros(int(GAP_S * VAD_RATE), dtype=np.int16)
    parts: list[np.ndarray] = []
    for index in range(len(SPOKEN)):
        parts += [corpus_utterance(index), gap]
    write_wav(path, np.concatenate(parts), VAD_RATE)
    return path


def at_24k(pcm: np.ndarray) -> bytes:
    """16 kHz VAD audio as the agent must send it: resampled to the session's 24 kHz."""
    resampler = StreamResampler(16000, 24000)
    return np.concatenate([resampler.push(pcm), resampler.flush()]).astype("<i2").tobytes()


@contextmanager
def node_process(module: str, namespace: str, *params: str) -> Iterator[tuple[subprocess.Popen[str], Output]]:
    args = ["--ros-args", "-r", f"__ns:={namespace}"]
    for param in params:
        args += ["-p", param]
    with running_process(python_module(f"by_your_command.nodes.{module}", *args)) as process:
        yield process, Output(process)


def test_a_wav_file_through_echo_control_vad_bridge_agent_to_player_and_command_processor(
    ros_namespace: str, tmp_path: Path
) -> None:
    replies = ("I see a door.", "Looking left.")
    heard = ("hello robot what do you see", "turn left and look at the door")
    script = Script(
        turns=(
            Turn(Say(replies[0]), heard=heard[0]),
            Turn(
                CallTool("robot_command", json.dumps({"command": "pan@left"}), Say(replies[1])),
                heard=heard[1],
            ),
        ),
        ms_per_char=MS_PER_CHAR,
    )
    recording = corpus_file(tmp_path / "microphone.wav")
    played = tmp_path / "played.wav"
    with ExitStack() as stack:
        openai = stack.enter_context(emulator(script))
        probe_ = stack.enter_context(probe_node(ros_namespace, "agent_probe"))
        probe = GraphProbe(probe_)
        utterances: list[AudioDataUtterance] = probe_.listen(AudioDataUtterance, "prompt_voice", RELIABLE)
        attention: list[String] = probe_.listen(String, "attention_state", LATCHED)
        spinner = threading.Thread(target=probe_.executor.spin, daemon=True)
        spinner.start()
        stack.callback(spinner.join, 5)
        stack.callback(probe_.executor.shutdown)

        player = stack.enter_context(player_process(ros_namespace, played))
        processor = stack.enter_context(processor_process(ros_namespace))
        echo, _ = stack.enter_context(node_process("echo_suppressor", ros_namespace, "mode:=gate"))
        vad, _ = stack.enter_context(node_process("silero_vad_node", ros_namespace))
        front = alive(player, processor, echo, vad)
        probe.wait_nodes(front, player=True, processor=True)
        graph, topic = probe_.node, probe_.topic
        until(
            lambda: (
                attention
                and graph.count_publishers(topic("audio_filtered")) >= 1
                and graph.count_subscribers(topic("audio_filtered")) >= 1
                and graph.count_subscribers(topic("assistant_speaking")) >= 2  # echo control + probe
            ),
            "echo control and the VAD wired",
            front,
            timeout=40,
        )
        assert attention[-1].data == "awake"

        port, _ = stack.enter_context(bridge_process(ros_namespace))
        config, settings = agent_config(tmp_path, openai.url, "robot", role="tools")
        agent, agent_out = stack.enter_context(agent_process(config, port))
        check = alive(agent, player, processor, echo, vad)
        probe.wait_agents_ready(ros_namespace, [setup_requests(settings)])

        source, _ = stack.enter_context(
            node_process(
                "file_audio_publisher", ros_namespace, f"files:=[{recording}]", "lead_silence_ms:=500",
                "chunk_samples:=1600",
            )
        )  # fmt: skip
        check = alive(agent, player, processor, echo, vad, source)

        until(lambda: len(probe.replies) >= 2, "both replies", check, timeout=40)
        until(lambda: sum(s.finished for s in list(probe.playback)) >= 2, "both replies played", check)
        ends = [u for u in list(utterances) if u.is_utterance_end]
        assert len(ends) == len(SPOKEN), "the VAD cut one utterance per sentence (no echo turn)"

        # Each utterance became one committed turn at the provider: its audio streamed, then commit,
        # then response.create; the tool call's result came back and asked for the spoken reply.
        flow = [
            t
            for t in openai.types()
            if t
            in (
                "input_audio_buffer.append",
                "input_audio_buffer.commit",
                "response.create",
                "conversation.item.create",
            )
        ]
        collapsed = [t for k, t in enumerate(flow) if k == 0 or t != flow[k - 1]]
        assert collapsed == [
            "input_audio_buffer.append", "input_audio_buffer.commit", "response.create",
            "input_audio_buffer.append", "input_audio_buffer.commit", "response.create",
            "conversation.item.create", "response.create",
        ], collapsed  # fmt: skip
        assert openai.connections() == 1

        # Not a sample lost between the VAD and the model: what was appended before each commit is
        # the utterance the VAD published, sample for sample, resampled to the session's 24 kHz.
        appended: list[bytes] = [b""]
        for record in openai.received():
            kind = record.event["type"]
            if kind == "input_audio_buffer.append":
                appended[-1] += base64.b64decode(record.event["audio"])
            elif kind == "input_audio_buffer.commit":
                appended.append(b"")
        by_utterance: dict[int, list[AudioDataUtterance]] = {}
        for chunk in list(utterances):
            by_utterance.setdefault(chunk.utterance_id, []).append(chunk)
        vad_pcm = [
            np.concatenate([np.asarray(c.int16_data, dtype=np.int16) for c in chunks])
            for _, chunks in sorted(by_utterance.items())
        ]
        assert appended[-1] == b"" and len(appended) == len(vad_pcm) + 1
        assert appended[:-1] == [at_24k(pcm) for pcm in vad_pcm]
        vad_ms = [1000 * len(pcm) / VAD_RATE for pcm in vad_pcm]
        for index, cut in enumerate(vad_ms):  # the whole sentence, with pre-roll and hangover
            assert cut >= len(corpus_utterance(index)) * 1000 / VAD_RATE

        # The transcripts and replies, the command routed with an accepted verdict
        assert probe.texts(probe.transcripts) == list(heard)
        assert probe.texts(probe.replies) == list(replies)
        verdict = until(lambda: list(probe.verdicts), "the command processor's verdict", check)[0]
        assert (verdict.raw, verdict.accepted) == ("pan@left", True)
        assert verdict.topic == f"{ros_namespace}/arm_preset"
        until(lambda: probe.texts(probe.arm) == ["pan@left"], "pan@left routed to arm_preset", check)
        outputs = [
            json.loads(event["item"]["output"])
            for event in openai.events("conversation.item.create")
            if event["item"]["type"] == "function_call_output"
        ]
        assert [(o["accepted"], o["command"]) for o in outputs] == [(True, verdict.command)]
        turns = until(
            lambda: (t := [r for r in probe.metric_records() if r["record"] == "turn"])[1:] and t,
            "both turn records",
            check,
        )
        assert [(t["turn_kind"], t["outcome"]) for t in turns] == [("voice", "completed")] * 2

        agent.send_signal(signal.SIGTERM)
        assert agent.wait(timeout=30) == 0, str(agent_out)
        assert FAKE_KEY not in "\n".join(agent_out.finish())
        player.send_signal(signal.SIGTERM)
        player.wait(timeout=30)

    # The player's WAV holds exactly the two replies, one after the other.
    audio, rate, _ = read_wav(played)
    assert rate == 24000
    assert audio.tobytes() == b"".join(speech_pcm(text, MS_PER_CHAR) for text in replies)
