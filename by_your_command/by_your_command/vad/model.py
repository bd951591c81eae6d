"""Silero VAD through onnxruntime, using the ONNX file shipped in the `silero-vad` wheel.

The `silero_vad` package itself imports torch, so it is located with find_spec and never imported.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import numpy.typing as npt
import onnxruntime

SAMPLE_RATE = 16000
WINDOW_SAMPLES = 512  # what Silero v5+ expects at 16 kHz (32 ms)
CONTEXT_SAMPLES = 64  # tail of the previous window, prepended to each input
MODEL_FILE = "silero_vad.onnx"


class ModelNotFoundError(RuntimeError):
    pass


def default_model_path() -> Path:
    """Path of silero_vad.onnx inside the installed silero-vad wheel (without importing it)."""
    spec = importlib.util.find_spec("silero_vad")
    if spec is None or not spec.submodule_search_locations:
        raise ModelNotFoundError(
            "the silero-vad package is not installed; install it with "
            "`pip install --no-deps 'silero-vad>=6.2'` (its own dependencies would pull in torch)"
        )
    path = Path(next(iter(spec.submodule_search_locations))) / "data" / MODEL_FILE
    if not path.is_file():
        raise ModelNotFoundError(f"{path} is missing from the silero-vad package")
    return path


class SileroModel:
    """Speech probability of consecutive 512-sample windows of 16 kHz float audio.

    Stateful (recurrent state plus the 64-sample context): feed windows in order and
    call `reset()` at a discontinuity (e.g. after sleeping).
    """

    def __init__(self, model_path: str | Path | None = None) -> None:
        options = onnxruntime.SessionOptions()
        # One thread each: inference is ~0.15 ms per window, thread hand-offs would cost more.
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        path = Path(model_path) if model_path else default_model_path()
        self._session = onnxruntime.InferenceSession(
            str(path), sess_options=options, providers=["CPUExecutionProvider"]
        )
        self._sr = np.array(SAMPLE_RATE, dtype=np.int64)
        self._input = np.zeros((1, CONTEXT_SAMPLES + WINDOW_SAMPLES), dtype=np.float32)
        self._state = np.zeros((2, 1, 128), dtype=np.float32)

    def reset(self) -> None:
        self._input[:] = 0.0
        self._state = np.zeros((2, 1, 128), dtype=np.float32)

    def probability(self, window: npt.NDArray[np.float32]) -> float:
        """Speech probability (0..1) of one window of exactly WINDOW_SAMPLES floats in [-1, 1)."""
        if window.shape != (WINDOW_SAMPLES,):
            raise ValueError(f"Silero needs windows of {WINDOW_SAMPLES} samples, got shape {window.shape}")
        # Shift the last 64 samples of the previous window into the context slot.
        self._input[0, :CONTEXT_SAMPLES] = self._input[0, -CONTEXT_SAMPLES:]
        self._input[0, CONTEXT_SAMPLES:] = window
        prob, self._state = self._session.run(
            None, {"input": self._input, "state": self._state, "sr": self._sr}
        )
        return float(prob[0, 0])
