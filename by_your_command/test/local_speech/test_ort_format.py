"""ort_format: the moonshine-cpp ORT-format files rewritten as ONNX compute the same, faster."""

from __future__ import annotations

import numpy as np
import onnxruntime
import pytest

from by_your_command.local_speech.moonshine import HEAD_DIM, HEADS, LAYERS, default_model_dir
from by_your_command.local_speech.ort_format import FormatError, _varint, onnx_model


def _session(model: bytes | str) -> onnxruntime.InferenceSession:
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = 1
    return onnxruntime.InferenceSession(model, sess_options=options, providers=["CPUExecutionProvider"])


def _first_step_feeds(hidden: np.ndarray) -> dict[str, np.ndarray]:
    feeds = {
        "input_ids": np.array([[1]], dtype=np.int64),
        "encoder_hidden_states": hidden,
        "use_cache_branch": np.array([False]),
    }
    empty = np.zeros((1, HEADS, 0, HEAD_DIM), dtype=np.float32)
    for layer in range(LAYERS):
        for part in ("decoder", "encoder"):
            for kind in ("key", "value"):
                feeds[f"past_key_values.{layer}.{part}.{kind}"] = empty
    return feeds


@pytest.mark.unit
def test_protobuf_varints_match_the_wire_format() -> None:
    assert _varint(1) == b"\x01"
    assert _varint(300) == b"\xac\x02"
    assert _varint(-1) == b"\xff" * 9 + b"\x01"  # int64 -1, as protobuf writes it


@pytest.mark.unit
def test_not_an_ort_file_is_refused() -> None:
    with pytest.raises(FormatError):
        onnx_model(b"\x08\x07" * 64)


@pytest.mark.unit
def test_the_rewritten_models_give_the_shipped_models_outputs() -> None:
    directory = default_model_dir()
    audio = np.random.default_rng(3).normal(0.0, 0.05, (1, 24000)).astype(np.float32)
    hidden = {}
    for source in ("ort", "onnx"):
        path = directory / "encoder_model.ort"
        encoder = _session(str(path) if source == "ort" else onnx_model(path.read_bytes()))
        hidden[source] = encoder.run(None, {"input_values": audio})[0]
    np.testing.assert_allclose(hidden["onnx"], hidden["ort"], atol=1e-4)
    path = directory / "decoder_model_merged.ort"
    shipped, rewritten = _session(str(path)), _session(onnx_model(path.read_bytes()))
    feeds = _first_step_feeds(hidden["ort"])
    expected = shipped.run(None, feeds)
    got = rewritten.run(None, feeds)
    assert [o.name for o in rewritten.get_outputs()] == [o.name for o in shipped.get_outputs()]
    for want, have in zip(expected, got, strict=True):
        np.testing.assert_allclose(have, want, atol=1e-3)
