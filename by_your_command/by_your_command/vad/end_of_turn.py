"""End of turn decided by an audio model after the VAD's short silence (optional; off by default).

The segmenter ends an utterance after `min_silence_duration_ms` of silence, which also cuts a
sentence at a mid-sentence pause ("go to the ... kitchen"). `EndOfTurn` sits after the segmenter:
at each utterance end it asks an end-of-turn model (Smart Turn v3.x: a Whisper-tiny encoder with a
binary head, an ONNX file bundled in the `pipecat-ai` wheel, BSD-2-Clause) whether the turn so far
sounds finished. Finished: the turn ends there. Not finished: it waits; speech that starts within
`incomplete_wait_ms` joins the same turn (the model is asked again at its end), otherwise the turn
ends when the wait runs out.

The model takes Whisper log-mel features of the last 8 s of the turn (left-padded with zeros),
computed here with numpy only (`whisper_log_mel`): no torch, no transformers. The ONNX path comes
from config; nothing is downloaded. No rclpy here.
"""

from __future__ import annotations

import importlib.util
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import numpy.typing as npt

from by_your_command.vad.segmenter import Event, UtteranceChunk, VoiceActivity

SAMPLE_RATE = 16000
WINDOW_S = 8  # the model sees the last 8 s of the turn
WINDOW_SAMPLES = WINDOW_S * SAMPLE_RATE
N_FFT = 400  # 25 ms analysis window
HOP = 160  # 10 ms
N_MELS = 80
N_FRAMES = WINDOW_SAMPLES // HOP  # 800 feature frames for 8 s
NS_PER_S = 1_000_000_000
BUNDLED_MODEL = "smart-turn-v3.2-cpu.onnx"  # inside pipecat-ai's wheel, pipecat/audio/turn/smart_turn/data

FloatArray = npt.NDArray[np.float32]
log = logging.getLogger(__name__)


class ModelNotFoundError(RuntimeError):
    pass


@dataclass(frozen=True)
class EndOfTurnConfig:
    model_path: str = field(
        default="",
        metadata={"help": "end-of-turn ONNX model (Smart Turn v3.x); empty: off, silence alone ends a turn"},
    )
    threshold: float = field(
        default=0.5, metadata={"help": "the turn is finished when the model's probability >= this"}
    )
    incomplete_wait_ms: int = field(
        default=2750,
        metadata={
            "help": "after the model says 'not finished', the turn still ends when no speech starts "
            "this long after the utterance end (with 250 ms of VAD silence: 3 s of silence in all)"
        },
    )
    threads: int = field(default=1, metadata={"help": "onnxruntime threads for the model"})

    def __post_init__(self) -> None:
        if not 0.0 < self.threshold < 1.0:  # also refuses NaN
            raise ValueError(f"threshold must be in (0, 1), got {self.threshold}")
        if not 0 <= self.incomplete_wait_ms <= 30_000:
            raise ValueError(f"incomplete_wait_ms must be in [0, 30000], got {self.incomplete_wait_ms}")
        if not 1 <= self.threads <= 8:
            raise ValueError(f"threads must be in 1..8, got {self.threads}")

    @property
    def enabled(self) -> bool:
        return bool(self.model_path)


def bundled_model_path() -> Path:
    """Smart Turn v3.2 inside an installed pipecat-ai wheel, found without importing pipecat
    (`pip install --no-deps pipecat-ai` is enough: only the ONNX file is used)."""
    spec = importlib.util.find_spec("pipecat")
    if spec is None or not spec.submodule_search_locations:
        raise ModelNotFoundError(
            "the pipecat-ai package is not installed; `pip install --no-deps pipecat-ai` brings the "
            "Smart Turn ONNX file (or set model_path to a copy of it)"
        )
    root = Path(next(iter(spec.submodule_search_locations)))
    path = root / "audio" / "turn" / "smart_turn" / "data" / BUNDLED_MODEL
    if not path.is_file():
        raise ModelNotFoundError(f"{path} is missing from the pipecat-ai package")
    return path


# --- Whisper log-mel features (what WhisperFeatureExtractor computes, re-derived with numpy) ---


def _hz_to_mel(hz: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """Slaney's mel scale: linear below 1 kHz, logarithmic above."""
    linear = 3.0 * hz / 200.0
    above = 15.0 + np.log(np.maximum(hz, 1e-9) / 1000.0) * (27.0 / math.log(6.4))
    return np.where(hz >= 1000.0, above, linear)


def _mel_to_hz(mel: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    linear = 200.0 * mel / 3.0
    above = 1000.0 * np.exp((mel - 15.0) * (math.log(6.4) / 27.0))
    return np.where(mel >= 15.0, above, linear)


def _mel_filters() -> npt.NDArray[np.float64]:
    """(N_MELS, N_FFT // 2 + 1) triangles over 0..8 kHz, each scaled to unit area (Slaney norm)."""
    edges = _mel_to_hz(np.linspace(0.0, float(_hz_to_mel(np.array([SAMPLE_RATE / 2.0]))[0]), N_MELS + 2))
    bins = np.linspace(0.0, SAMPLE_RATE / 2.0, N_FFT // 2 + 1)
    lower, centre, upper = edges[:-2, None], edges[1:-1, None], edges[2:, None]
    rising = (bins[None, :] - lower) / (centre - lower)
    falling = (upper - bins[None, :]) / (upper - centre)
    triangles = np.maximum(0.0, np.minimum(rising, falling))
    return np.asarray(triangles * (2.0 / (upper - lower)), dtype=np.float64)


_FILTERS = _mel_filters()
_HANN = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(N_FFT) / N_FFT)  # periodic, as torch's


def fit_window(audio: FloatArray) -> FloatArray:
    """The last 8 s of `audio`, left-padded with zeros when shorter (the model's training framing)."""
    samples: FloatArray = np.asarray(audio, dtype=np.float32)
    if len(samples) >= WINDOW_SAMPLES:
        return samples[-WINDOW_SAMPLES:]
    return np.concatenate([np.zeros(WINDOW_SAMPLES - len(samples), np.float32), samples])


def whisper_log_mel(window: FloatArray) -> FloatArray:
    """(80, 800) log-mel features of exactly 8 s of 16 kHz audio, as Whisper's feature extractor
    with do_normalize: zero-mean unit-variance waveform, centred 400-point STFT every 160 samples
    (reflect padding), power through Slaney mel filters, log10 floored 8 decades below the peak,
    then (x + 4) / 4; the STFT's last frame is dropped."""
    if window.shape != (WINDOW_SAMPLES,):
        raise ValueError(f"features need {WINDOW_SAMPLES} samples, got shape {window.shape}")
    x = window.astype(np.float32)
    x = (x - x.mean()) / np.sqrt(x.var() + 1e-7)
    padded = np.pad(x.astype(np.float64), N_FFT // 2, mode="reflect")
    frames = np.lib.stride_tricks.sliding_window_view(padded, N_FFT)[::HOP][:N_FRAMES]
    power = np.abs(np.fft.rfft(frames * _HANN, axis=-1)) ** 2  # (800, 201)
    log_mel = np.log10(np.maximum(_FILTERS @ power.T, 1e-10))  # (80, 800)
    log_mel = np.maximum(log_mel, log_mel.max() - 8.0)
    features: FloatArray = ((log_mel + 4.0) / 4.0).astype(np.float32)
    return features


class CompletionModel(Protocol):
    def completion_probability(self, audio: FloatArray) -> float:
        """Probability (0..1) that the turn in `audio` (16 kHz floats, oldest first) is finished."""
        ...


class SmartTurnModel:
    """Smart Turn v3.x through onnxruntime: input_features (batch, 80, 800) -> probability (batch, 1)."""

    def __init__(self, model_path: str | Path, threads: int = 1) -> None:
        import onnxruntime

        path = Path(model_path)
        if not path.is_file():
            raise ModelNotFoundError(f"end-of-turn model {path} does not exist")
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self._session = onnxruntime.InferenceSession(
            str(path), sess_options=options, providers=["CPUExecutionProvider"]
        )
        inputs = self._session.get_inputs()
        if len(inputs) != 1 or list(inputs[0].shape[1:]) != [N_MELS, N_FRAMES]:
            shapes = [(i.name, i.shape) for i in inputs]
            raise ValueError(f"{path} is not a Smart Turn v3 model: inputs {shapes}")
        self._input = inputs[0].name

    def completion_probability(self, audio: FloatArray) -> float:
        features = whisper_log_mel(fit_window(audio))[np.newaxis]
        (out,) = self._session.run(None, {self._input: features})[:1]
        return float(np.asarray(out).reshape(-1)[0])


@dataclass(frozen=True)
class TurnEnd:
    time_ns: int  # when it was decided (the closing frame's time, or the wait's deadline)
    reason: str  # "complete" (the model said so) or "timeout" (no speech within the wait)
    probability: float  # the model's last verdict on this turn


@dataclass
class _Utterance:
    utterance_id: int
    start_ns: int  # time of the first sample held (later than the id once old chunks are dropped)
    chunks: list[UtteranceChunk]


class EndOfTurn:
    """Segmenter events in, turn ends out. Feed every event in order (`push`) and the stream's time
    (`tick`, e.g. per audio block) so that a wait can run out. Not thread-safe."""

    def __init__(
        self, config: EndOfTurnConfig, model: CompletionModel, sample_rate: int = SAMPLE_RATE
    ) -> None:
        if sample_rate != SAMPLE_RATE:
            raise ValueError(f"the end-of-turn model runs at {SAMPLE_RATE} Hz, got {sample_rate}")
        self._config = config
        self._model = model
        self._wait_ns = config.incomplete_wait_ms * 1_000_000
        self._utterances: list[_Utterance] = []  # of the open turn, within the last 8 s
        self._in_utterance = False
        self._deadline_ns: int | None = None  # the open turn ends here unless speech starts
        self._probability = 0.0
        self.model_calls = 0
        self.bad_outputs = 0

    @property
    def turn_open(self) -> bool:
        return bool(self._utterances)

    def push(self, events: list[Event]) -> list[TurnEnd]:
        ends: list[TurnEnd] = []
        for event in events:
            if isinstance(event, UtteranceChunk):
                self._add_chunk(event)
            elif event.active:
                self._in_utterance = True
                self._deadline_ns = None  # speech resumed: the turn goes on
            elif self._utterances:
                self._in_utterance = False
                end = self._judge(event)
                if end is not None:
                    ends.append(end)
        return ends

    def tick(self, now_ns: int) -> TurnEnd | None:
        """The turn's end when the wait after a 'not finished' verdict has run out by `now_ns`."""
        if self._deadline_ns is None or self._in_utterance or now_ns < self._deadline_ns:
            return None
        end = TurnEnd(self._deadline_ns, "timeout", self._probability)
        self._close()
        return end

    def finish(self) -> TurnEnd | None:
        """End an open turn now (sleep, mute, end of stream)."""
        if not self._utterances:
            return None
        end = TurnEnd(self._deadline_ns or 0, "timeout", self._probability)
        self._close()
        return end

    def turn_audio(self) -> FloatArray:
        """The open turn's last 8 s as 16 kHz floats, silence between utterances as zeros."""
        if not self._utterances:
            return np.zeros(0, np.float32)
        first = self._utterances[0].start_ns
        pieces: list[FloatArray] = []
        position = 0  # samples since `first`
        for utterance in self._utterances:
            offset = (utterance.start_ns - first) * SAMPLE_RATE // NS_PER_S
            if offset > position:
                pieces.append(np.zeros(offset - position, np.float32))
                position = offset
            for chunk in utterance.chunks:
                pieces.append(chunk.samples.astype(np.float32) / 32768.0)
                position += len(chunk.samples)
        return np.concatenate(pieces)[-WINDOW_SAMPLES:] if pieces else np.zeros(0, np.float32)

    def _add_chunk(self, chunk: UtteranceChunk) -> None:
        if not self._utterances or self._utterances[-1].utterance_id != chunk.utterance_id:
            self._utterances.append(_Utterance(chunk.utterance_id, chunk.utterance_id, []))
        self._utterances[-1].chunks.append(chunk)
        self._drop_old()

    def _drop_old(self) -> None:
        """Keep memory bounded: chunks wholly older than the newest sample's last 8 s go."""
        newest = self._utterances[-1]
        newest_end = newest.start_ns + sum(len(c.samples) for c in newest.chunks) * NS_PER_S // SAMPLE_RATE
        horizon = newest_end - WINDOW_S * NS_PER_S
        while len(self._utterances) > 1 or len(self._utterances[0].chunks) > 1:
            oldest = self._utterances[0]
            first_end = oldest.start_ns + len(oldest.chunks[0].samples) * NS_PER_S // SAMPLE_RATE
            if first_end > horizon:
                break
            oldest.chunks.pop(0)
            oldest.start_ns = first_end
            if not oldest.chunks:
                self._utterances.pop(0)

    def _judge(self, end: VoiceActivity) -> TurnEnd | None:
        self.model_calls += 1
        self._probability = self._model.completion_probability(self.turn_audio())
        if not 0.0 <= self._probability <= 1.0:  # NaN too: a broken model must not hold turns open
            self.bad_outputs += 1
            log.warning("end-of-turn model returned %r; the turn ends on silence", self._probability)
            self._probability = 1.0
        if self._probability >= self._config.threshold:
            self._close()
            return TurnEnd(end.time_ns, "complete", self._probability)
        self._deadline_ns = end.time_ns + self._wait_ns
        return None

    def _close(self) -> None:
        self._utterances = []
        self._deadline_ns = None
        self._in_utterance = False
