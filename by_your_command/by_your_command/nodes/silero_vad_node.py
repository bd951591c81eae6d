"""silero_vad_node: audio (AudioChunk, any block size) -> voice_activity + prompt_voice utterance chunks.

Listens on `input_topic` (default `audio_filtered`; set it to `audio`, or remap, when there is no
echo control); with `echo_gate` it ignores its input while `assistant_speaking` and a tail after
(half duplex in one hop: the profiles' gate echo mode runs no echo_suppressor), but hears an
utterance begun before the robot spoke to its end (vad/half_duplex.py). Sleep/wake via
`wake_cmd`, mute via `voice_active`, wake/sleep phrases on `prompt_text`, and (`spoken_wake`) a
wake phrase spoken while asleep, decoded here; the state is latched on `attention_state`. Logic
lives in by_your_command.vad.

Safety stop (`stop_spotter`): every input block (or every block of `stop_input_topic`, the raw mic
in aec mode) also goes to a local stop spotter
(by_your_command.safety) before any gate, sleep or mute check, so a spoken "stop" is heard while
the robot speaks, asleep and muted. A stop publishes `stop` on `response_cmd`, a blanket cut on
`interruption_signal` (reason "safety_stop"), the phrase on `safety_stop`, and says "Stopping."
on `response_voice`. The robot's own voice is recognised through `audio_played`.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Time
from by_your_command_msgs.msg import AudioChunk, AudioDataUtterance, Interruption, SafetyStop
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Bool, String

from by_your_command.audio import echo_memory
from by_your_command.audio.pcm import Int16Array, resample
from by_your_command.local_speech.speaker import Speaker, SpeakerConfig, SpeechError
from by_your_command.nodes._audio_msgs import int16_field, make_audio_chunk, pcm_of
from by_your_command.nodes._delivery import DeliveryCheck
from by_your_command.nodes._params import declare_config
from by_your_command.nodes._qos import AUDIO_IN, LATCHED, RELIABLE
from by_your_command.safety.spotter import Detection, StopSpotter
from by_your_command.safety.worker import SpotterWorker
from by_your_command.vad.attention import Attention, AttentionState, PhraseCommand, PhraseMatcher
from by_your_command.vad.config import VadConfig
from by_your_command.vad.detector import VoiceDetector
from by_your_command.vad.half_duplex import HalfDuplexGate
from by_your_command.vad.model import SileroModel
from by_your_command.vad.segmenter import Event, UtteranceChunk, VoiceActivity
from by_your_command.vad.spoken_wake import (
    RecognizerUnavailableError,
    UtteranceCollector,
    WakeRecognizer,
    WakeResult,
    WakeWorker,
)

NS_PER_S = 1_000_000_000
STATS_PERIOD_S = 10.0
# Audio timeout and delivery checks: each executor wake-up costs ~0.5 ms, so not more often.
HOUSEKEEPING_PERIOD_S = 0.5
STOP_VOICE_CHUNK_S = 0.25  # "Stopping." goes out in chunks this long (the player's usual diet)
SPANS_KEPT = 16  # recent utterances a safety stop may name


def _to_time(ns: int) -> Time:
    return Time(sec=ns // NS_PER_S, nanosec=ns % NS_PER_S)


def _to_ns(stamp: Time) -> int:
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


class SileroVadNode(Node):
    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__("silero_vad_node", parameter_overrides=parameter_overrides)
        self.config = declare_config(self, VadConfig)
        self.detector = VoiceDetector(self.config, SileroModel())
        self.attention = Attention(awake=self.config.start_awake)
        self.phrases = PhraseMatcher(
            self.config.wake_phrases, self.config.sleep_phrases, self.config.robot_name
        )
        self.activity_pub = self.create_publisher(Bool, "voice_activity", RELIABLE)
        self.voice_pub = self.create_publisher(AudioDataUtterance, "prompt_voice", RELIABLE)
        self.delivery = DeliveryCheck(self.voice_pub, self.config.delivery_confirm_s)
        self.state_pub = self.create_publisher(String, "attention_state", LATCHED)
        self.create_subscription(AudioChunk, self.config.input_topic, self._on_audio, AUDIO_IN)
        self.create_subscription(Bool, "wake_cmd", self._on_wake_cmd, RELIABLE)
        self.create_subscription(Bool, "voice_active", self._on_voice_active, RELIABLE)
        self.create_subscription(String, "prompt_text", self._on_prompt_text, RELIABLE)
        self._gate: HalfDuplexGate | None = None
        if self.config.echo_gate:
            self._gate = HalfDuplexGate(self.config.gate_tail_ms, self.config.gate_hold_ms)
            self.create_subscription(Bool, "assistant_speaking", self._on_speaking, LATCHED)
        self.blocks_ignored = 0  # arrived while asleep or muted
        self.blocks_gated = 0  # captured while the assistant spoke (echo_gate)
        self.blocks_rejected = 0  # malformed
        self.publish_failures = 0
        self.utterances = 0
        self.unheard_utterances = 0  # published to no subscriber, or none acknowledged it: lost
        self._listeners = 0  # prompt_voice subscribers matched, as last logged
        self._reported: tuple[int, ...] = ()
        self._last_audio = time.monotonic()
        self._last_report = time.monotonic()
        # Spoken wake: the detector keeps segmenting while asleep, utterances go to a local
        # recognizer and never to a publisher. _epoch tags each one, so a result that arrives
        # after the state changed (a clap woke it, it slept again) is not obeyed.
        self._asleep_audio = False  # the detector holds audio heard while asleep
        self._epoch = 0
        self._results: deque[tuple[int, WakeResult | Exception]] = deque()
        self._results_lock = threading.Lock()
        self.spoken_wakes = 0
        self.wake_rejections = 0
        self._collector = UtteranceCollector()
        self._wake_worker = self._start_spoken_wake()
        self._safety = self._start_safety_stop()
        self.create_timer(HOUSEKEEPING_PERIOD_S, self._housekeeping)
        self._publish_state()
        self.get_logger().info(
            f"VAD ready on '{self.config.input_topic}': threshold={self.config.threshold} "
            f"min_silence={self.config.min_silence_duration_ms} ms pre_roll={self.config.pre_roll_frames} "
            f"chunk={self.config.utterance_chunk_frames} frames, "
            f"echo gate {self._gate_summary()}, "
            f"{self.attention.state.value}"
        )

    def _gate_summary(self) -> str:
        if self._gate is None:
            return "off"
        return f"on (tail {self.config.gate_tail_ms} ms, hold {self.config.gate_hold_ms} ms)"

    def _start_spoken_wake(self) -> WakeWorker | None:
        if not self.config.spoken_wake:
            self.get_logger().info("spoken wake off (spoken_wake: false): only wake_cmd and prompt_text wake")
            return None
        try:
            recognizer = WakeRecognizer(
                self.config.wake_phrases, self.config.sleep_phrases, self.config.robot_name
            )
        except RecognizerUnavailableError as error:
            self.get_logger().warning(f"spoken wake off: {error}")
            return None
        self._wake_guard = self.create_guard_condition(self._on_wake_results)
        self.get_logger().info(f"spoken wake on: {list(recognizer.phrases)} heard while asleep wake it")
        return WakeWorker(recognizer.recognize, self._wake_result, self._wake_result)

    def _start_safety_stop(self) -> SpotterWorker | None:
        """The stop spotter and its publishers; a bad stop_* parameter raises here (at start)."""
        config = self.config.stop_config
        self.safety_stops = 0
        self.safety_rejected_blocks = 0
        self._stops_heard: deque[Detection | Exception] = deque()
        self._spans: deque[tuple[int, int | None]] = deque(maxlen=SPANS_KEPT)  # (utterance id, end ns)
        self._span_samples = 0
        self._stop_memory: Path | None = None
        self._stop_was_cancelling = False
        if not config.enabled:
            self.get_logger().warning("safety stop OFF (stop_spotter: false): a spoken 'stop' is not heard")
            return None
        cancel = self.config.stop_cancels_echo
        self._stop_voice = self._synthesize_stop_voice(config.reply_text)
        spotter = StopSpotter(config, cancel_echo=cancel, voice_sample=self._voice_sample())
        if spotter.echo_controller is not None:
            name = f"{self.get_fully_qualified_name()}/stop_spotter"
            self._stop_memory = echo_memory.memory_file(config.echo_memory, name)
        if self._stop_memory is not None:
            self._log_echo_memory(echo_memory.restore(spotter.echo_controller, self._stop_memory))
        topic = self.config.stop_topic
        if topic != self.config.input_topic:
            # Its own input (aec mode: the raw mic beside audio_filtered): the echo_suppressor's
            # residual suppression and echo muting took the user's stop with the robot's voice.
            self.create_subscription(AudioChunk, topic, self._spot, AUDIO_IN)
        self.cmd_pub = self.create_publisher(String, "response_cmd", RELIABLE)
        self.interruption_pub = self.create_publisher(Interruption, "interruption_signal", RELIABLE)
        self.safety_pub = self.create_publisher(SafetyStop, "safety_stop", RELIABLE)
        self.stop_voice_pub = self.create_publisher(AudioChunk, "response_voice", RELIABLE)
        # The robot's voice as played: the spotter rejects a stop the robot said itself.
        self.create_subscription(AudioChunk, "audio_played", self._on_played, AUDIO_IN)
        self._stop_guard = self.create_guard_condition(self._on_stops_heard)
        self.get_logger().info(
            f"safety stop on: {list(config.stop_phrases)} ({config.language}) heard in every state, "
            f"mic '{topic}' {'echo-cancelled with audio_played' if cancel else 'as received'}, "
            f"reply {config.reply_text!r}"
        )
        return SpotterWorker(spotter, self._stop_heard, self._stop_heard)

    def _remember_stop_echo(self, final: bool = False) -> None:
        """Keep what the spotter's canceller learned when a reply it cancelled is over (and at
        shutdown): the next start hears a stop over its first reply (audio/echo_memory.py)."""
        if self._safety is None or self._stop_memory is None:
            return
        spotter = self._safety.spotter
        cancelling = spotter.cancelling
        if spotter.echo_controller is not None and (final or (self._stop_was_cancelling and not cancelling)):
            outcome = echo_memory.keep(spotter.echo_controller, self._stop_memory)
            if outcome is not None and not outcome.ok:
                self._log_echo_memory(outcome)
        self._stop_was_cancelling = cancelling

    def _log_echo_memory(self, outcome: echo_memory.Outcome) -> None:
        if outcome.ok:
            self.get_logger().info(f"safety stop: {outcome.message}")
        else:
            self.get_logger().warning(f"safety stop: {outcome.message}", throttle_duration_sec=60.0)

    def _voice_sample(self) -> Int16Array | None:
        """The robot's "Stopping." at 16 kHz, a sample of its voice for the spotter (none if silent)."""
        if self._stop_voice is None:
            return None
        pcm_bytes, rate = self._stop_voice
        return resample(np.frombuffer(pcm_bytes, dtype="<i2").astype(np.int16), rate, 16000)

    def _synthesize_stop_voice(self, text: str) -> tuple[bytes, int] | None:
        if not text:
            return None
        try:
            return Speaker(SpeakerConfig()).say(text)
        except (SpeechError, ValueError) as error:  # the stop still routes; only the voice is missing
            self.get_logger().error(f"safety stop: cannot synthesize {text!r} ({error}): it stops silently")
            return None

    def _stop_heard(self, result: Detection | Exception) -> None:
        """Spotter thread: hand the stop to the executor."""
        with self._results_lock:
            self._stops_heard.append(result)
        self._stop_guard.trigger()

    def _on_stops_heard(self) -> None:
        with self._results_lock:
            results = list(self._stops_heard)
            self._stops_heard.clear()
        for result in results:
            if isinstance(result, Exception):
                errors = self._safety.errors if self._safety else 0
                self.get_logger().error(f"safety stop: spotter failed ({errors} so far): {result!r}")
            else:
                self._safety_stop(result)

    def _safety_stop(self, detection: Detection) -> None:
        """One hop, no LLM: stop the robot, cut the reply, tell the agents, say so."""
        now = int(self.get_clock().now().nanoseconds)
        self.safety_stops += 1
        cut = Interruption(stream_id="", reason="safety_stop")  # every reply begun until now
        cut.header.stamp = _to_time(now)
        # Each on its own: one publish failing (RCLError under overload) must not keep the others.
        self._publish_safely(lambda: self.cmd_pub.publish(String(data="stop")))  # first: the motion
        self._publish_safely(lambda: self.interruption_pub.publish(cut))
        self._publish_safely(lambda: self.safety_pub.publish(self._safety_stop_msg(detection)))
        self._publish_safely(lambda: self._say_stopping(now + 1_000_000))  # after the cut: kept
        self.get_logger().warning(
            f"SAFETY STOP #{self.safety_stops}: heard {detection.text!r}, "
            f"{(now - detection.voice_end_ns) / 1e6:.0f} ms after the word ended; `stop` routed, replies cut"
        )
        # DDS drops what a publisher sends before it has matched a subscriber: say so, never silently.
        if self.cmd_pub.get_subscription_count() == 0:
            self.get_logger().error("SAFETY STOP reached no one: nothing subscribes to response_cmd")
        if self.safety_pub.get_subscription_count() == 0:
            self.get_logger().warning("safety stop: nothing subscribes to safety_stop: no agent was told")

    def _safety_stop_msg(self, detection: Detection) -> SafetyStop:
        """The stop, naming the published utterance that holds its word (utterance ids are the mic
        time of their first sample, the spotter's clock): the agents must not take it as a request."""
        msg = SafetyStop(phrase=detection.text[:200], utterance_id=self._utterance_of(detection))
        msg.word_start = _to_time(detection.voice_start_ns)
        msg.word_end = _to_time(detection.voice_end_ns)
        return msg

    def _utterance_of(self, detection: Detection) -> int:
        for utterance_id, end_ns in reversed(self._spans):  # the newest first
            if utterance_id <= detection.voice_end_ns and (
                end_ns is None or end_ns >= detection.voice_start_ns
            ):
                return utterance_id
        return 0

    def _publish_safely(self, publish: Callable[[], None]) -> None:
        try:
            publish()
        except Exception as error:  # rclpy raises RCLError under overload: count, never crash
            self.publish_failures += 1
            self.get_logger().error(f"safety stop publish failed ({self.publish_failures} so far): {error}")

    def _say_stopping(self, stamp_ns: int) -> None:
        if self._stop_voice is None:
            return
        pcm_bytes, rate = self._stop_voice
        pcm = np.frombuffer(pcm_bytes, dtype=np.int16)
        stream_id = f"safety-stop-{self.safety_stops}"
        step = int(STOP_VOICE_CHUNK_S * rate)
        offsets = list(range(0, len(pcm), step)) or [0]
        for index, offset in enumerate(offsets):
            stamp = _to_time(stamp_ns + offset * NS_PER_S // rate)  # each chunk's first sample
            chunk = make_audio_chunk(pcm[offset : offset + step], rate, 1, stamp, stream_id)
            chunk.end_of_stream = index == len(offsets) - 1
            self.stop_voice_pub.publish(chunk)

    def _on_played(self, msg: AudioChunk) -> None:
        if self._safety is None:
            return
        stamp = _to_ns(msg.header.stamp)
        if len(msg.data) == 0 or stamp == 0:  # an end marker, or nothing to place in time
            return
        self._safety.reference(pcm_of(msg), int(msg.sample_rate), int(msg.channels), stamp)

    def _spot(self, msg: AudioChunk) -> None:
        """Every block, in every state, goes to the stop spotter first."""
        if self._safety is None:
            return
        stamp = _to_ns(msg.header.stamp) or int(self.get_clock().now().nanoseconds)
        rate, channels = int(msg.sample_rate), int(msg.channels)
        if not 8000 <= rate <= 192_000 or not 1 <= channels <= 8 or len(msg.data) % channels:
            self.safety_rejected_blocks += 1  # the detector reports it too, when it runs
            return
        self._safety.mic(pcm_of(msg), rate, channels, stamp)

    def _wake_result(self, epoch: int, result: WakeResult | Exception) -> None:
        """Worker thread: hand the result to the executor (attention is only touched there)."""
        with self._results_lock:
            self._results.append((epoch, result))
        self._wake_guard.trigger()

    def _on_wake_results(self) -> None:
        with self._results_lock:
            results = list(self._results)
            self._results.clear()
        for epoch, result in results:
            if isinstance(result, Exception):
                errors = self._wake_worker.errors if self._wake_worker else 0
                self.get_logger().error(f"spoken wake: recognizer failed ({errors} so far): {result!r}")
            elif epoch != self._epoch or self.attention.state is not AttentionState.ASLEEP:
                self.get_logger().info("spoken wake: result for an earlier state ignored")
            elif result.wake:
                self.spoken_wakes += 1
                self.get_logger().info(f"'wake' phrase heard in speech: {result.text!r}")
                self._change(self.attention.set_awake(True))
            else:
                # What was said while asleep stays private: the transcript is not logged.
                self.wake_rejections += 1
                self.get_logger().info(f"spoken wake: not a wake phrase ({self.wake_rejections} so far)")

    def _on_speaking(self, msg: Bool) -> None:
        if self._gate is None:  # not subscribed without it
            return
        now = int(self.get_clock().now().nanoseconds)
        cut = self._gate.set_speaking(bool(msg.data), now, mid_utterance=self.detector.in_utterance)
        if cut and self.detector.streaming:
            # From now on the mic hears the robot: what the detector holds (pre-roll, or an
            # utterance the hold does not cover) ends here, not when the audio timeout notices.
            self._stop_detector()

    def _gated(self, msg: AudioChunk) -> bool:
        if self._gate is None:
            return False
        rate = int(msg.sample_rate) * max(int(msg.channels), 1)  # per sample of len(msg.data)
        now = int(self.get_clock().now().nanoseconds)
        return not self._gate.admits(_to_ns(msg.header.stamp), len(msg.data), rate, now)

    def _on_audio(self, msg: AudioChunk) -> None:
        self._last_audio = time.monotonic()
        if self.config.stop_topic == self.config.input_topic:
            self._spot(msg)  # before the gate, sleep and mute: safety hears everything
        if self._gated(msg):
            self.blocks_gated += 1
            if self.detector.streaming:  # a held utterance reached the end of its hold
                self._stop_detector()
        elif self.attention.listening:
            self._publish(self._held(self._detect(msg)))
        elif self._wake_worker is not None and self.attention.state is AttentionState.ASLEEP:
            self._asleep_audio = True
            self._hear_asleep(self._held(self._detect(msg)))
        else:
            self.blocks_ignored += 1

    def _held(self, events: list[Event]) -> list[Event]:
        """While an utterance is held through the robot's speech: its events up to its end. What
        follows in the block is the robot's voice, and anything it started is dropped unheard."""
        if self._gate is None or not self._gate.holding:
            return events
        for index, event in enumerate(events):
            if isinstance(event, VoiceActivity) and not event.active:
                self._gate.release()
                self.detector.stop()
                return events[: index + 1]
        return events

    def _hear_asleep(self, events: list[Event]) -> None:
        """Whole utterances go to the recognizer; nothing (not even voice_activity) is published."""
        if self._wake_worker is None:
            return
        for pcm, rate in self._collector.feed(events):
            self._wake_worker.submit(self._epoch, pcm, rate)

    def _detect(self, msg: AudioChunk) -> list[Event]:
        stamp = _to_ns(msg.header.stamp)
        stamped = stamp != 0
        if not stamped:  # the arrival time, used only if this block starts a stream
            stamp = int(self.get_clock().now().nanoseconds)
        gaps_before = self.detector.discontinuities
        try:
            events = self.detector.process(
                pcm_of(msg), int(msg.sample_rate), int(msg.channels), stamp, stamped=stamped
            )
        except ValueError as error:
            self.blocks_rejected += 1
            self.get_logger().error(
                f"bad audio chunk dropped ({self.blocks_rejected} so far): {error}", throttle_duration_sec=5.0
            )
            return []
        if self.detector.discontinuities != gaps_before and self.detector.last_discontinuity is not None:
            gap = self.detector.last_discontinuity
            self.get_logger().info(
                f"audio {gap.reason} of {gap.offset_ns / 1e6:+.0f} ms: new stream "
                f"({self.detector.discontinuities} so far)",
                throttle_duration_sec=1.0,
            )
        return events

    def _on_wake_cmd(self, msg: Bool) -> None:
        self._change(self.attention.set_awake(bool(msg.data)))

    def _on_voice_active(self, msg: Bool) -> None:
        self._change(self.attention.set_muted(not msg.data))

    def _on_prompt_text(self, msg: String) -> None:
        command = self.phrases.match(msg.data)
        if command is not None:
            self.get_logger().info(f"'{command.value}' phrase heard in prompt_text")
            self._change(self.attention.set_awake(command is PhraseCommand.WAKE))

    def _change(self, changed: bool) -> None:
        if not changed:
            return
        # What the detector holds belongs to the state being left: awake audio is closed with its
        # end marker, asleep audio is dropped. Either way no stale pre-roll survives the change.
        events = self.detector.stop()
        if self._gate is not None:
            self._gate.release()
        if self._asleep_audio:
            self._collector.reset()
        else:
            self._publish(events)
        self._asleep_audio = False
        self._epoch += 1
        self._publish_state()

    def _stop_detector(self) -> None:
        """Audio stopped: close the open utterance where it belongs (published, or decoded)."""
        if self._gate is not None:
            self._gate.release()
        if self._asleep_audio:
            self._hear_asleep(self.detector.stop())
        else:
            self._publish(self.detector.stop())

    def _publish_state(self) -> None:
        self.state_pub.publish(String(data=self.attention.state.value))
        self.get_logger().info(f"attention: {self.attention.state.value}")

    def _publish(self, events: list[Event]) -> None:
        for event in events:
            try:
                if isinstance(event, VoiceActivity):
                    self.activity_pub.publish(Bool(data=event.active))
                    self.utterances += int(event.active)
                elif isinstance(event, UtteranceChunk):
                    # Judged at the end: DDS's subscriber count lags a new match by a moment (a
                    # chunk lost before it is the agent's to report, as a missing chunk).
                    unheard = event.is_utterance_end and self.voice_pub.get_subscription_count() == 0
                    if unheard:
                        self._unheard(
                            event.utterance_id,
                            "nothing subscribes to prompt_voice (no bridge or agent listening)",
                        )
                    self.voice_pub.publish(self._utterance_msg(event))
                    self._track_span(event)
                    confirm = event.is_utterance_end and not unheard
                    self.delivery.published(event.utterance_id if confirm else None)
            except Exception as error:  # rclpy raises RCLError under overload: count, never crash
                self.publish_failures += 1
                self.get_logger().error(f"publish failed ({self.publish_failures} so far): {error}")

    def _track_span(self, chunk: UtteranceChunk) -> None:
        """The published utterances' spans on the mic clock (id = first sample): the safety stop
        names the one that holds its word. Open ones end at None."""
        if chunk.chunk_sequence == 0 or not self._spans or self._spans[-1][0] != chunk.utterance_id:
            self._spans.append((chunk.utterance_id, None))
            self._span_samples = 0
        self._span_samples += len(chunk.samples)
        end = chunk.utterance_id + self._span_samples * NS_PER_S // chunk.sample_rate
        self._spans[-1] = (chunk.utterance_id, end if chunk.is_utterance_end else None)

    def _unheard(self, utterance_id: int, why: str, certain: bool = True) -> None:
        # DDS drops what nobody (alive) receives without a word: say it here, where it is known.
        self.unheard_utterances += 1
        self.get_logger().warning(
            f"utterance {utterance_id} {'is' if certain else 'may be'} lost: {why}; "
            f"{self.unheard_utterances} unheard so far"
        )

    @staticmethod
    def _utterance_msg(chunk: UtteranceChunk) -> AudioDataUtterance:
        msg = AudioDataUtterance(
            utterance_id=chunk.utterance_id,
            is_utterance_end=chunk.is_utterance_end,
            chunk_sequence=chunk.chunk_sequence,
            sample_rate=chunk.sample_rate,
            channels=1,
            unvoiced_samples=chunk.unvoiced_samples,
        )
        msg.int16_data = int16_field(chunk.samples)
        return msg

    def _housekeeping(self) -> None:
        listeners = self.voice_pub.get_subscription_count()
        if listeners != self._listeners:  # a bridge or agent came or went (a dead one: ~20 s later)
            self.get_logger().info(f"prompt_voice subscribers: {self._listeners} -> {listeners}")
            self._listeners = listeners
        for utterance_id in self.delivery.unacknowledged():
            # Lost if the subscriber died before receiving it; received, if it died after that but
            # before its acknowledgement was due: the VAD cannot tell which.
            why = "prompt_voice's subscribers did not acknowledge it (a bridge that died?)"
            self._unheard(utterance_id, why, certain=False)
        now = time.monotonic()
        if self.detector.streaming and now - self._last_audio > self.config.audio_timeout_ms / 1000:
            # Audio stopped (mic unplugged, echo gate shut): whatever comes next is a new stream.
            if self.detector.in_utterance:
                self.get_logger().warning("audio stopped mid-utterance: closing the utterance")
            self._stop_detector()
        self._remember_stop_echo()
        if now - self._last_report >= STATS_PERIOD_S:
            self._last_report = now
            self._report()

    def _report(self) -> None:
        current = (
            self.detector.frames,
            self.utterances,
            self.blocks_ignored,
            self.blocks_gated,
            self.blocks_rejected,
            self.publish_failures,
            self.detector.discontinuities,
            self.unheard_utterances,
            self._wake_worker.decoded if self._wake_worker else 0,
            self._wake_worker.errors if self._wake_worker else 0,
            self._safety.blocks if self._safety else 0,
        )
        if current != self._reported:
            self._reported = current
            self.get_logger().info(
                f"frames={current[0]} utterances={current[1]} ignored_blocks={current[2]} "
                f"gated_blocks={current[3]} rejected_blocks={current[4]} publish_failures={current[5]} "
                f"stream_restarts={current[6]} unheard_utterances={current[7]} "
                f"resampled_blocks={self.detector.resampled_blocks}{self._spoken_wake_stats()}"
                f"{self._safety_stats()}"
            )

    def _safety_stats(self) -> str:
        worker = self._safety
        if worker is None:
            return " safety_stop: OFF"
        spotter = worker.spotter
        return (
            f" safety_stop: stops={self.safety_stops} heard={spotter.heard} own_voice={spotter.own_voice}"
            f" residual_echo={spotter.residual_echo} near_misses={spotter.near_misses}"
            f" repeated={spotter.repeated}"
            f" dropped={worker.dropped} errors={worker.errors} rejected_blocks={self.safety_rejected_blocks}"
        )

    def _spoken_wake_stats(self) -> str:
        worker = self._wake_worker
        if worker is None:
            return ""
        return (
            f" spoken_wake: decoded={worker.decoded} woke={self.spoken_wakes} rejected={self.wake_rejections}"
            f" dropped={worker.dropped} too_long={self._collector.too_long} errors={worker.errors}"
        )

    def before_shutdown(self) -> None:
        """Called by run_node on SIGINT/SIGTERM while the context is alive: an open utterance gets
        its end marker and voice_activity goes False, so consumers never wait for an end."""
        if self._asleep_audio:
            self.detector.stop()  # asleep audio is never published, not even its end
        elif self.detector.in_utterance:
            self.get_logger().info("shutting down mid-utterance: closing it")
            self._publish(self.detector.stop())

    def destroy_node(self) -> None:
        self.before_shutdown()  # when destroyed without run_node (tests, benchmarks)
        if self._wake_worker is not None:
            self._wake_worker.close()
        if self._safety is not None:
            self._safety.close()
            self._remember_stop_echo(final=True)
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    from by_your_command.nodes._runtime import run_node

    run_node(SileroVadNode, args if args is not None else sys.argv)


if __name__ == "__main__":
    main()
