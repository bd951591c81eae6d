"""simple_audio_player in a real graph with a WAV sink: status, assistant_speaking, interruption."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from by_your_command_msgs.msg import AudioChunk, PlaybackStatus
from byc_testing import python_module, running_process, wait_for
from ros_probe import probe_node
from std_msgs.msg import Bool

from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

VOICE_RATE = 24000


@pytest.mark.ros
def test_player_plays_reports_and_stops_on_interruption(ros_namespace: str, tmp_path: Path) -> None:
    wav = tmp_path / "played.wav"
    command = python_module(
        "by_your_command.nodes.simple_audio_player",
        "--ros-args", "-r", f"__ns:={ros_namespace}",
        "-p", "sink:=wav", "-p", f"wav_path:={wav}", "-p", "sample_rate:=16000", "-p", "block_ms:=20",
    )  # fmt: skip
    with probe_node(ros_namespace) as probe, running_process(command) as node:
        voice = probe.node.create_publisher(AudioChunk, "response_voice", RELIABLE)
        interrupt = probe.node.create_publisher(Bool, "interruption_signal", RELIABLE)
        speaking = probe.listen(Bool, "assistant_speaking", LATCHED)
        status = probe.listen(PlaybackStatus, "playback_status", RELIABLE)
        played = probe.listen(AudioChunk, "audio_played", STREAM)

        def spin_alive() -> None:
            assert node.poll() is None, node.stdout.read() if node.stdout else "player died"
            probe.spin(0.01)

        def ready() -> bool:
            spin_alive()
            return (
                voice.get_subscription_count() > 0
                and interrupt.get_subscription_count() > 0
                and bool(speaking)
            )

        wait_for(ready, timeout=20, what="the player to come up and latch assistant_speaking")
        assert speaking[-1].data is False

        t = np.arange(4 * VOICE_RATE) / VOICE_RATE
        pcm = np.rint(6000 * np.sin(2 * np.pi * 330 * t)).astype(np.int16)
        for k in range(0, len(pcm), 2400):  # 4 s of speech in 100 ms chunks
            voice.publish(make_audio_chunk(pcm[k : k + 2400], VOICE_RATE, 1, stream_id="resp-1"))
            probe.spin(0.0)

        def playing_for(ms: int) -> bool:
            spin_alive()
            return any(s.stream_id == "resp-1" and s.played_ms >= ms for s in status)

        wait_for(lambda: playing_for(300), timeout=10, what="300 ms of resp-1 played")
        assert speaking[-1].data is True
        assert played and played[0].sample_rate == 16000 and played[0].stream_id == "resp-1"
        assert all(len(chunk.data) <= 320 for chunk in played)

        interrupt.publish(Bool(data=True))
        interrupted_at = time.monotonic()

        def silenced() -> bool:
            spin_alive()
            return speaking[-1].data is False and any(s.interrupted for s in status)

        wait_for(silenced, timeout=5, what="assistant_speaking False and an interrupted status")
        reaction_ms = (time.monotonic() - interrupted_at) * 1000
        final = [s for s in status if s.interrupted][-1]
        assert final.stream_id == "resp-1" and final.queued_ms == 0 and not final.finished
        assert 300 <= final.played_ms < 3000
        assert reaction_ms < 2000  # generous: the bound that matters is measured by bench_player

    # The node stopped cleanly: the WAV holds what was played, far less than the 4 s sent.
    from by_your_command.audio.pcm import read_wav

    samples, rate, _ = read_wav(wav)
    assert rate == 16000
    assert 0.3 * rate <= len(samples) < 3 * rate
