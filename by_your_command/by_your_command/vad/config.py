"""Parameters of the Silero VAD node: the one place their defaults live."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from by_your_command.safety.config import DEFAULT_STOP_PHRASES, StopConfig
from by_your_command.vad.attention import PhraseMatcher

DEFAULT_WAKE_PHRASES = ["wake up", "wakeup", "awaken", "wake"]
DEFAULT_SLEEP_PHRASES = ["go to sleep", "sleeptime", "sleep"]
_TOPIC = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_]*(?:/[A-Za-z_][A-Za-z0-9_]*)*$")  # a ROS name, no ~ or {}


@dataclass(frozen=True)
class VadConfig:
    threshold: float = field(
        default=0.5, metadata={"help": "speech starts when Silero's probability >= this"}
    )
    neg_threshold: float = field(
        default=-1.0,
        metadata={"help": "silence counts when probability < this (hysteresis); < 0 means threshold - 0.15"},
    )
    min_silence_duration_ms: int = field(
        default=250, metadata={"help": "silence that ends an utterance (ms)"}
    )
    pre_roll_frames: int = field(
        default=15, metadata={"help": "512-sample frames before the onset included in the utterance"}
    )
    max_buffer_frames: int = field(
        default=250,
        metadata={"help": "most frames held before publishing (bounds memory in whole-utterance mode)"},
    )
    utterance_chunk_frames: int = field(
        default=10, metadata={"help": "frames per prompt_voice chunk; 0 = one chunk per utterance"}
    )
    sample_rate: int = field(default=16000, metadata={"help": "rate the VAD runs at (Silero: 16000)"})
    audio_timeout_ms: int = field(
        default=1000,
        metadata={"help": "close an open utterance when no audio arrives this long (mic stopped, gate shut)"},
    )
    gap_tolerance_ms: int = field(
        default=100,
        metadata={
            "help": "a block stamped this much later (or earlier) than the previous one's end starts a new "
            "stream: the open utterance ends, pre-roll and model state are dropped"
        },
    )
    delivery_confirm_s: float = field(
        default=6.0,
        metadata={
            "help": "an utterance no prompt_voice subscriber acknowledged this long after the last publish "
            "is reported lost (a bridge killed without closing stays matched for ~20 s); acknowledgements "
            "come with DDS heartbeats, up to 3 s apart with Fast DDS: keep it above that"
        },
    )
    start_awake: bool = field(default=True, metadata={"help": "listen from startup (else wait for wake)"})
    wake_phrases: list[str] = field(
        default_factory=lambda: list(DEFAULT_WAKE_PHRASES),
        metadata={"help": "prompt_text commands that wake the VAD (the whole text must be one)"},
    )
    sleep_phrases: list[str] = field(
        default_factory=lambda: list(DEFAULT_SLEEP_PHRASES),
        metadata={"help": "prompt_text commands that put the VAD to sleep (the whole text must be one)"},
    )
    spoken_wake: bool = field(
        default=True,
        metadata={
            "help": "while asleep, decode each utterance on the robot (pocketsphinx) and wake on a spoken "
            "wake phrase; asleep audio is never published. Off with a log line if pocketsphinx is missing"
        },
    )
    robot_name: str = field(
        default="", metadata={"help": "a name that may start or end a command ('Barney, wake up')"}
    )
    input_topic: str = field(
        default="audio_filtered", metadata={"help": "audio input (AudioChunk); 'audio' without echo control"}
    )
    echo_gate: bool = field(
        default=False,
        metadata={
            "help": "half duplex without an echo_suppressor: ignore the input while assistant_speaking is "
            "true and gate_tail_ms after (the profiles' gate echo mode)"
        },
    )
    gate_tail_ms: int = field(
        default=300,
        metadata={"help": "echo_gate: keep ignoring the input this long after the assistant stops"},
    )
    gate_hold_ms: int = field(
        default=2000,
        metadata={
            "help": "echo_gate: an utterance the user began before the assistant started speaking is heard "
            "to its end, for at most this long after the assistant started (0: it ends there)"
        },
    )
    # The safety stop (by_your_command.safety): its defaults live in StopConfig, not here.
    stop_spotter: bool = field(
        default=StopConfig.enabled,
        metadata={
            "help": "spot stop phrases on the robot in every state (while it speaks, asleep, muted) and "
            "route `stop` without any LLM. Off only where nothing moves"
        },
    )
    stop_language: str = field(default=StopConfig.language, metadata={"help": "language of the stop phrases"})
    stop_phrases: list[str] = field(
        default_factory=lambda: list(DEFAULT_STOP_PHRASES[StopConfig.language]),
        metadata={"help": "stop phrases (lower-case words); empty = stop_language's defaults"},
    )
    stop_reply_text: str = field(
        default=StopConfig.reply_text, metadata={"help": "said when a stop is heard ('' = silent)"}
    )
    stop_refractory_ms: int = field(
        default=StopConfig.refractory_ms,
        metadata={"help": "a stop heard this soon after the last one is not acted on again"},
    )
    stop_min_level_dbfs: float = field(
        default=StopConfig.min_level_dbfs,
        metadata={"help": "quieter audio is never decoded (an idle room costs nothing)"},
    )
    stop_onset_db: float = field(
        default=StopConfig.onset_db, metadata={"help": "speech starts this far above the noise floor"}
    )
    stop_end_silence_ms: int = field(
        default=StopConfig.end_silence_ms,
        metadata={"help": "quiet that ends an utterance (most of the latency)"},
    )
    stop_end_drop_db: float = field(
        default=StopConfig.end_drop_db,
        metadata={"help": "over the robot's voice: this far under an utterance's loudest is a pause"},
    )
    stop_max_utterance_ms: int = field(
        default=StopConfig.max_utterance_ms,
        metadata={"help": "longer speech is a sentence, not a stop, and is not decoded"},
    )
    stop_max_other_words: int = field(
        default=StopConfig.max_other_words,
        metadata={"help": "other words a stop utterance may hold (recognition slips); never a negation"},
    )
    stop_own_voice_window_ms: int = field(
        default=StopConfig.own_voice_window_ms,
        metadata={"help": "a stop within this of the robot's own stop-like word (audio_played) is its echo"},
    )
    stop_cancel_echo: bool = field(
        default=StopConfig.cancel_echo,
        metadata={
            "help": "the spotter hears the mic with the robot's voice cancelled (aec engine, audio_played) "
            "under echo_gate, or when stop_input_topic is its own"
        },
    )
    stop_echo_memory: str = field(
        default=StopConfig.echo_memory,
        metadata={
            "help": "what the spotter's echo canceller learned, kept across restarts (a stop over the "
            "first reply after a start is heard): auto ($XDG_STATE_HOME/by_your_command/echo_path/"
            "<node>.stop_spotter.npz), none, or a path"
        },
    )
    stop_input_topic: str = field(
        default="",
        metadata={
            "help": "the spotter's audio; '' = input_topic. Another topic (the raw mic `audio` when "
            "input_topic is audio_filtered) is echo-cancelled by the spotter itself (stop_cancel_echo)"
        },
    )

    def __post_init__(self) -> None:
        self.stop_config  # noqa: B018  raises ValueError on a bad stop_* parameter
        if self.stop_input_topic and not _TOPIC.match(self.stop_input_topic):
            raise ValueError(
                f"stop_input_topic {self.stop_input_topic!r} is not a topic name ('' = input_topic)"
            )
        if not 0.0 < self.threshold < 1.0:
            raise ValueError(f"threshold must be in (0, 1), got {self.threshold}")
        if self.neg_threshold >= self.threshold:
            raise ValueError(
                f"neg_threshold ({self.neg_threshold}) must be below threshold ({self.threshold})"
            )
        if self.min_silence_duration_ms < 0:
            raise ValueError(f"min_silence_duration_ms must be >= 0, got {self.min_silence_duration_ms}")
        if self.pre_roll_frames < 0:
            raise ValueError(f"pre_roll_frames must be >= 0, got {self.pre_roll_frames}")
        if self.max_buffer_frames < 1:
            raise ValueError(f"max_buffer_frames must be >= 1, got {self.max_buffer_frames}")
        if self.utterance_chunk_frames < 0:
            raise ValueError(f"utterance_chunk_frames must be >= 0, got {self.utterance_chunk_frames}")
        if self.audio_timeout_ms <= 0:
            raise ValueError(f"audio_timeout_ms must be > 0, got {self.audio_timeout_ms}")
        if not 0.0 < self.delivery_confirm_s <= 3600.0:  # also refuses NaN
            raise ValueError(f"delivery_confirm_s must be in (0, 3600], got {self.delivery_confirm_s}")
        if not 0 <= self.gate_tail_ms <= 10_000:
            raise ValueError(f"gate_tail_ms must be in [0, 10000], got {self.gate_tail_ms}")
        if not 0 <= self.gate_hold_ms <= 10_000:
            raise ValueError(f"gate_hold_ms must be in [0, 10000], got {self.gate_hold_ms}")
        if self.gap_tolerance_ms <= 0:
            raise ValueError(f"gap_tolerance_ms must be > 0, got {self.gap_tolerance_ms}")
        PhraseMatcher(self.wake_phrases, self.sleep_phrases, self.robot_name)  # raises on a bad phrase
        if self.sample_rate != 16000:
            raise ValueError(f"Silero runs at 16000 Hz here, got sample_rate={self.sample_rate}")

    @property
    def stop_config(self) -> StopConfig:
        return StopConfig(
            enabled=self.stop_spotter,
            language=self.stop_language,
            phrases=tuple(self.stop_phrases),
            reply_text=self.stop_reply_text,
            refractory_ms=self.stop_refractory_ms,
            min_level_dbfs=self.stop_min_level_dbfs,
            onset_db=self.stop_onset_db,
            end_silence_ms=self.stop_end_silence_ms,
            end_drop_db=self.stop_end_drop_db,
            max_utterance_ms=self.stop_max_utterance_ms,
            max_other_words=self.stop_max_other_words,
            own_voice_window_ms=self.stop_own_voice_window_ms,
            cancel_echo=self.stop_cancel_echo,
            echo_memory=self.stop_echo_memory,
        )

    @property
    def stop_topic(self) -> str:
        """The topic the stop spotter hears."""
        return self.stop_input_topic or self.input_topic

    @property
    def stop_cancels_echo(self) -> bool:
        """The spotter cancels the robot's voice itself: its input still holds it (echo_gate's raw
        mic, or a topic of its own beside an echo-cancelled input_topic)."""
        own_input = self.stop_topic != self.input_topic
        return self.stop_spotter and self.stop_cancel_echo and (self.echo_gate or own_input)

    @property
    def gap_tolerance_ns(self) -> int:
        return self.gap_tolerance_ms * 1_000_000

    @property
    def effective_neg_threshold(self) -> float:
        return self.neg_threshold if self.neg_threshold >= 0 else max(self.threshold - 0.15, 0.0)

    def min_silence_frames(self, frame_samples: int) -> int:
        frames = math.ceil(self.min_silence_duration_ms * self.sample_rate / 1000 / frame_samples)
        return max(frames, 1)

    @property
    def frames_per_chunk(self) -> int:
        """Interim chunks are cut at this many frames (whole-utterance mode still honours the bound)."""
        if self.utterance_chunk_frames == 0:
            return self.max_buffer_frames
        return min(self.utterance_chunk_frames, self.max_buffer_frames)
