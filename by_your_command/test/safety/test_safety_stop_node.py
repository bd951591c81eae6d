"""The safety stop through the real VAD node (a process): a spoken stop in gate mode while the
robot speaks, asleep and muted routes `stop`, cuts the replies, tells the agents and says
"Stopping."; the robot's own stop, played into the mic with its reference, does not; a bad stop
configuration stops the node at start."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from audio_io.synthetic_room import ROBOT_REPLY, at_level, espeak, trim_silence
from audio_io.synthetic_room import Room as EchoRoom
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance, Interruption, SafetyStop
from byc_testing import running_process
from ros_probe import Probe, probe_node
from safety.test_spotter import said
from std_msgs.msg import Bool, String
from vad.test_graph import alive, node, spin_until

from by_your_command.audio.pcm import Int16Array
from by_your_command.nodes._audio_msgs import make_audio_chunk
from by_your_command.nodes._qos import LATCHED, RELIABLE, STREAM

RATE = 16000
BLOCK = 512
NS = 1_000_000_000


class Room:
    """Publishes the mic (`audio`) and, when the robot speaks, what it played (`audio_played`)
    as stamped blocks on one continuous timeline; the mic hears the robot 120 ms late."""

    def __init__(self, probe: Probe) -> None:
        self.probe = probe
        self.mic = probe.node.create_publisher(AudioChunk, "audio", STREAM)
        self.played = probe.node.create_publisher(AudioChunk, "audio_played", STREAM)
        self.next_ns = probe.node.get_clock().now().nanoseconds

    def play(
        self,
        user: Int16Array | None = None,
        robot: Int16Array | None = None,
        realtime: bool = False,
        echo: Int16Array | None = None,
        quiet_after_s: float = 1.0,
    ) -> None:
        """`realtime`: one block per block's duration, as a microphone does (a long reply sent
        faster than the spotter cancels and decodes it would overflow its bounded queue). `echo`:
        the robot as the mic hears it (default: half its level, 120 ms late)."""
        length = max(len(user) if user is not None else 0, len(robot) if robot is not None else 0)
        mic = np.zeros(length + int(quiet_after_s * RATE), dtype=np.int32)
        if user is not None:
            mic[: len(user)] += user
        delay = int(0.12 * RATE)
        if echo is not None:
            mic[: len(echo)] += echo
        elif robot is not None:
            mic[delay : delay + len(robot)] += robot // 2
        mic16 = np.clip(mic, -32768, 32767).astype(np.int16)
        started = time.monotonic()
        for k in range(0, len(mic16) - BLOCK + 1, BLOCK):
            stamp = Time(sec=self.next_ns // NS, nanosec=self.next_ns % NS)
            if robot is not None and k < len(robot):
                self.played.publish(make_audio_chunk(robot[k : k + BLOCK], RATE, 1, stamp, "reply-1"))
            self.mic.publish(make_audio_chunk(mic16[k : k + BLOCK], RATE, 1, stamp))
            self.next_ns += BLOCK * NS // RATE
            self.probe.spin(0.002)
            while realtime and time.monotonic() < started + (k + BLOCK) / RATE:
                self.probe.spin(0.002)


def wait_for_the_node(
    probe: Probe, check: Callable[[], None], states: list[String], room: Room, played: bool = False
) -> None:
    """Up: its attention state latched, the mic (and with `played`, audio_played) subscribed."""

    def ready() -> bool:
        heard = room.mic.get_subscription_count() and (not played or room.played.get_subscription_count())
        return bool(states and heard)

    spin_until(probe, check, ready, timeout=30, what="the VAD node")


@contextmanager
def the_robot_speaking(
    ros_namespace: str, *params: str
) -> Iterator[tuple[Probe, Callable[[], None], Room, list[SafetyStop]]]:
    """The VAD node in gate mode (and `params`), up, told the robot speaks (its spotter cancels the
    robot's voice itself): the probe, the node's liveness check, the room and the safety stops heard."""
    command = node("silero_vad_node", ros_namespace, "input_topic:=audio", "echo_gate:=true", *params)
    with probe_node(ros_namespace) as probe, running_process(command) as vad:
        check = alive(vad)
        states = probe.listen(String, "attention_state", LATCHED)
        stops = probe.listen(SafetyStop, "safety_stop", RELIABLE)
        speaking = probe.node.create_publisher(Bool, "assistant_speaking", LATCHED)
        room = Room(probe)
        wait_for_the_node(probe, check, states, room, played=True)
        speaking.publish(Bool(data=True))
        yield probe, check, room, stops


@pytest.mark.ros
def test_a_spoken_stop_is_obeyed_while_the_robot_speaks_asleep_and_muted_but_not_its_own(
    ros_namespace: str,
) -> None:
    # Without the spotter's echo cancellation the robot's voice reaches it whole (the worst case,
    # e.g. before AEC3 has converged): only its reference on audio_played can reject it.
    command = node(
        "silero_vad_node", ros_namespace, "input_topic:=audio", "echo_gate:=true", "stop_cancel_echo:=false"
    )
    with probe_node(ros_namespace) as probe, running_process(command) as vad:
        check = alive(vad)
        states = probe.listen(String, "attention_state", LATCHED)
        cuts = probe.listen(Interruption, "interruption_signal", RELIABLE)
        commands = probe.listen(String, "response_cmd", RELIABLE)
        stops = probe.listen(SafetyStop, "safety_stop", RELIABLE)
        utterances = probe.listen(AudioDataUtterance, "prompt_voice", RELIABLE)
        voice = probe.listen(AudioChunk, "response_voice", RELIABLE)
        speaking = probe.node.create_publisher(Bool, "assistant_speaking", LATCHED)
        wake = probe.node.create_publisher(Bool, "wake_cmd", RELIABLE)
        voice_active = probe.node.create_publisher(Bool, "voice_active", RELIABLE)
        room = Room(probe)

        def wait(condition: object, what: str) -> None:
            spin_until(probe, check, condition, timeout=30, what=what)  # type: ignore[arg-type]

        wait(
            lambda: states and room.mic.get_subscription_count() and room.played.get_subscription_count(),
            "the VAD node to come up",
        )
        speaking.publish(Bool(data=True))  # the robot is speaking: gate mode closes the VAD's input
        wait(lambda: probe.node.count_subscribers(probe.topic("assistant_speaking")) >= 1, "the gate")

        # The robot's own stop, heard back by the mic, with what it played on audio_played.
        room.play(robot=said("stop it"))
        room.play(robot=said("Stopping."))
        # Then the user, during the reply: the stop is obeyed.
        room.play(user=said("halt"))
        # What the stop does comes on several topics: each arrival is waited for, none assumed.
        wait(
            lambda: len(stops) == 1 and commands and cuts and len(voice) >= 1 and voice[-1].end_of_stream,
            "the first stop",
        )
        assert [c.data for c in commands] == ["stop"]
        assert len(cuts) == 1 and cuts[0].reason == "safety_stop" and cuts[0].stream_id == ""
        assert cuts[0].action == Interruption.CUT
        assert stops[0].phrase == "halt" and stops[0].utterance_id == 0  # the gate: no utterance of it
        stamp = lambda m: m.header.stamp.sec * NS + m.header.stamp.nanosec  # noqa: E731
        assert {c.stream_id for c in voice} == {"safety-stop-1"}
        assert all(stamp(c) > stamp(cuts[0]) for c in voice)  # the player keeps it after the cut

        speaking.publish(Bool(data=False))
        wake.publish(Bool(data=False))
        wait(lambda: states[-1].data == "asleep", "sleep")
        room.play(user=said("stop it"))
        said_stopping = lambda: len({c.stream_id for c in voice})  # noqa: E731
        routed = lambda n: len(stops) == n and len(commands) == n and said_stopping() == n  # noqa: E731
        wait(lambda: routed(2), "a stop while asleep")

        wake.publish(Bool(data=True))
        voice_active.publish(Bool(data=False))
        wait(lambda: states[-1].data == "muted", "mute")
        room.play(user=said("freeze"))
        wait(lambda: routed(3), "a stop while muted")
        assert [c.data for c in commands] == ["stop"] * 3
        assert [s.utterance_id for s in stops] == [0, 0, 0]  # asleep and muted: nothing went to agents

        # Awake, the robot silent: the stop is also an utterance on prompt_voice, and the stop names
        # it, so an agent does not take it as a request (it would route stop again, and answer).
        voice_active.publish(Bool(data=True))
        wait(lambda: states[-1].data == "awake", "unmute")
        room.play(user=said("stop"))
        wait(lambda: len(stops) == 4 and any(u.is_utterance_end for u in utterances), "a stop while awake")
        assert stops[3].utterance_id != 0
        assert stops[3].utterance_id in {u.utterance_id for u in utterances}
        word_end = stops[3].word_end.sec * NS + stops[3].word_end.nanosec
        assert stops[3].utterance_id < word_end  # the utterance began before the word ended


@pytest.mark.ros
def test_in_aec_mode_the_spotter_hears_the_raw_mic_beside_audio_filtered(ros_namespace: str) -> None:
    command = node("silero_vad_node", ros_namespace, "input_topic:=audio_filtered", "stop_input_topic:=audio")
    with probe_node(ros_namespace) as probe, running_process(command) as vad:
        check = alive(vad)
        states = probe.listen(String, "attention_state", LATCHED)
        stops = probe.listen(SafetyStop, "safety_stop", RELIABLE)
        room = Room(probe)  # publishes the mic on `audio` only
        wait_for_the_node(probe, check, states, room)
        room.play(user=said("halt"))
        spin_until(probe, check, lambda: len(stops) == 1, timeout=30, what="the stop")
        assert stops[0].phrase == "halt"
    # Nothing here subscribes to response_cmd: the stop reached no command processor, and the node
    # says so (DDS drops what a publisher sends unmatched, without a word).
    output = vad.stdout.read() if vad.stdout else ""
    assert "SAFETY STOP reached no one: nothing subscribes to response_cmd" in output


@pytest.mark.ros
def test_a_lone_dont_said_over_the_robots_reply_is_a_stop(ros_namespace: str) -> None:
    # Over the robot's voice a "stop" whose /s/ is clipped is decoded "don't" (and "Don't!" alone
    # means stop): through the node, with the spotter cancelling the robot's voice itself (gate).
    with the_robot_speaking(ros_namespace) as (probe, check, room, stops):
        commands = probe.listen(String, "response_cmd", RELIABLE)
        reply = at_level(trim_silence(espeak(ROBOT_REPLY, "en-gb", RATE), RATE), -16.0)
        user = np.zeros(len(reply), dtype=np.int16)
        word = at_level(trim_silence(espeak("Don't!", "en-us", RATE), RATE), -26.0)
        user[int(3.5 * RATE) : int(3.5 * RATE) + len(word)] = word
        room.play(user=user, robot=reply, realtime=True)
        spin_until(probe, check, lambda: stops and commands, timeout=30, what="the stop")
        assert [s.phrase for s in stops] == ["don't"] and [c.data for c in commands] == ["stop"]


@pytest.mark.ros
def test_a_stop_over_the_reply_is_decided_at_its_pause_not_after_the_echo(ros_namespace: str) -> None:
    # The robot's residual echo stays above the floor after the user's word and held the
    # utterance's end back (bench_safety_stop: +55 ms median, +330 ms p95): a clean stop is decided
    # at the pause under its level (stop_end_drop_db). Through the node on the real clock, the mic
    # goes quiet (nothing more published) 150 ms after the word: the stop must come from that.
    with the_robot_speaking(ros_namespace) as (probe, check, room, stops):
        reply = at_level(trim_silence(espeak(ROBOT_REPLY, "en-gb", RATE), RATE), -16.0)
        echo = at_level(EchoRoom().echo(reply, RATE), -22.0)  # with the room's reverberation
        room.play(robot=reply, echo=echo, realtime=True)  # the canceller converges, as on a robot
        word = at_level(trim_silence(espeak("stop", "en-us", RATE), RATE), -26.0)
        word_at = int(2.5 * RATE)
        cut = word_at + len(word) + int(0.15 * RATE)
        user = np.zeros(cut, dtype=np.int16)
        user[word_at : word_at + len(word)] = word
        began = room.next_ns
        room.play(user=user, robot=reply[:cut], echo=echo[:cut], realtime=True, quiet_after_s=0.0)
        spin_until(probe, check, lambda: stops, timeout=20, what="the stop, 150 ms of audio after it")
        assert [s.phrase for s in stops] == ["stop"]
        word_start = began + word_at * NS // RATE
        stamped = stops[0].word_end.sec * NS + stops[0].word_end.nanosec
        # In the word (its closing /p/ is weak: the stamp may be at its vowel), not in the echo.
        assert word_start < stamped <= word_start + len(word) * NS // RATE


@pytest.mark.ros
def test_a_restarted_node_hears_a_stop_early_in_its_first_reply(ros_namespace: str, tmp_path: Path) -> None:
    # A new spotter's canceller needs seconds of the robot's voice: a stop 1 s into the first
    # reply after a start was mostly missed. The node keeps what it learned when a reply is over
    # (stop_echo_memory) and a restart starts from it.
    kept = tmp_path / "stop_spotter.npz"
    reply = at_level(trim_silence(espeak(ROBOT_REPLY, "en-gb", RATE), RATE), -16.0)
    echo = at_level(EchoRoom().echo(reply, RATE), -22.0)
    with the_robot_speaking(ros_namespace, f"stop_echo_memory:={kept}") as (probe, check, room, stops):
        room.play(robot=reply, echo=echo, realtime=True, quiet_after_s=2.0)  # the reply, then quiet
        spin_until(probe, check, kept.exists, timeout=10, what="what the spotter's canceller learned, kept")
        assert not stops
    with the_robot_speaking(ros_namespace, f"stop_echo_memory:={kept}") as (probe, check, room, stops):
        word = at_level(trim_silence(espeak("stop", "en-us", RATE), RATE), -26.0)
        word_at = RATE  # 1 s into the first reply since the start
        cut = word_at + len(word) + RATE
        user = np.zeros(cut, dtype=np.int16)
        user[word_at : word_at + len(word)] = word
        room.play(user=user, robot=reply[:cut], echo=echo[:cut], realtime=True, quiet_after_s=0.0)
        spin_until(probe, check, lambda: stops, timeout=20, what="the stop 1 s into the first reply")
        assert [s.phrase for s in stops] == ["stop"]


@pytest.mark.ros
def test_the_robot_called_by_name_through_the_node_is_not_stopped(ros_namespace: str) -> None:
    # A lone "Robot?" was heard "oh halt" in these voices and stopped the robot (bench_safety_stop,
    # lone_words). A stop said after it is the marker that the node has judged what came before.
    command = node("silero_vad_node", ros_namespace, "input_topic:=audio", "echo_gate:=true")
    with probe_node(ros_namespace) as probe, running_process(command) as vad:
        check = alive(vad)
        states = probe.listen(String, "attention_state", LATCHED)
        stops = probe.listen(SafetyStop, "safety_stop", RELIABLE)
        room = Room(probe)
        wait_for_the_node(probe, check, states, room)
        for voice in ("en-us-nyc", "en-gb-x-gbcwmd"):
            room.play(user=said("robot", voice), realtime=True)
        room.play(user=said("stop it"), realtime=True)
        spin_until(probe, check, lambda: stops, timeout=30, what="the stop after the names")
        assert [s.phrase for s in stops] == ["stop it"]


@pytest.mark.ros
@pytest.mark.parametrize(
    "param", ["stop_language:=klingon", "stop_phrases:=[stop,blorptastic]", "stop_input_topic:=blorp//tastic"]
)
def test_a_bad_stop_configuration_stops_the_node_at_start(ros_namespace: str, param: str) -> None:
    command = node("silero_vad_node", ros_namespace, "input_topic:=audio", param)
    with running_process(command) as vad:
        output, _ = vad.communicate(timeout=60)
    assert vad.returncode != 0
    assert "klingon" in output or "blorptastic" in output or "blorp//tastic" in output
