"""Spoken wake while asleep: the local recognizer (real pocketsphinx on espeak-ng speech made at
test time), the utterance collector and the decoding worker."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from byc_testing import wait_for

from by_your_command.audio.pcm import Int16Array, read_wav, resample, to_mono
from by_your_command.vad.config import DEFAULT_SLEEP_PHRASES, DEFAULT_WAKE_PHRASES, VadConfig
from by_your_command.vad.segmenter import UtteranceChunk, VoiceActivity
from by_your_command.vad.spoken_wake import (
    MAX_UTTERANCE_S,
    UtteranceCollector,
    WakeRecognizer,
    WakeResult,
    WakeWorker,
)

RATE = 16000
PRE_ROLL = np.zeros(int(0.48 * RATE), dtype=np.int16)  # what the VAD puts before speech
HANGOVER = np.zeros(int(0.3 * RATE), dtype=np.int16)  # and after it


def espeak(text: str, voice: str, tmp: Path) -> Int16Array:
    """`text` spoken by espeak-ng, 16 kHz mono, framed like a VAD utterance."""
    binary = shutil.which("espeak-ng")
    assert binary, "espeak-ng is missing: run scripts/bootstrap.sh"
    wav = tmp / f"{voice}_{abs(hash(text))}.wav"
    subprocess.run([binary, "-v", voice, "-w", str(wav), text], check=True, capture_output=True)
    pcm, rate, channels = read_wav(wav)
    return np.concatenate([PRE_ROLL, resample(to_mono(pcm, channels), rate, RATE), HANGOVER])


@pytest.fixture(scope="module")
def recognizer() -> WakeRecognizer:
    return WakeRecognizer(DEFAULT_WAKE_PHRASES, DEFAULT_SLEEP_PHRASES)


@pytest.mark.unit
@pytest.mark.parametrize("voice", ["en-us", "en-us+f3"])
def test_wake_up_is_heard_in_two_voices(recognizer: WakeRecognizer, voice: str, tmp_path: Path) -> None:
    result = recognizer.recognize(espeak("wake up", voice, tmp_path), RATE)
    assert result.wake, result


@pytest.mark.unit
@pytest.mark.parametrize(
    "text",
    [
        "don't wake the baby",  # a wake word inside a sentence, negated
        "I can't wake up early",  # the whole wake phrase inside a sentence
        "look down",  # a robot command
        "what time is it",  # chat
    ],
)
def test_other_speech_does_not_wake(recognizer: WakeRecognizer, text: str, tmp_path: Path) -> None:
    result = recognizer.recognize(espeak(text, "en-us", tmp_path), RATE)
    assert not result.wake, result


@pytest.mark.unit
def test_noise_and_silence_do_not_wake(recognizer: WakeRecognizer) -> None:
    noise = np.random.default_rng(7).normal(0, 3000, 2 * RATE).clip(-32768, 32767).astype(np.int16)
    assert not recognizer.recognize(noise, RATE).wake
    assert not recognizer.recognize(np.zeros(RATE, dtype=np.int16), RATE).wake


@pytest.mark.unit
def test_other_rates_are_resampled(recognizer: WakeRecognizer, tmp_path: Path) -> None:
    speech = resample(espeak("wake up", "en-us", tmp_path), RATE, 48000)
    assert recognizer.recognize(speech, 48000).wake


@pytest.mark.unit
def test_a_phrase_the_dictionary_lacks_is_skipped_not_fatal() -> None:
    only = WakeRecognizer(["wake up", "zzyzxq"], DEFAULT_SLEEP_PHRASES)
    assert only.phrases == ("wake up",)
    with pytest.raises(ValueError, match="no wake phrase can be spoken"):
        WakeRecognizer(["zzyzxq"], DEFAULT_SLEEP_PHRASES)


def chunk(samples: int, sequence: int, end: bool, value: int = 1) -> UtteranceChunk:
    return UtteranceChunk(
        utterance_id=1,
        chunk_sequence=sequence,
        is_utterance_end=end,
        samples=np.full(samples, value, dtype=np.int16),
        sample_rate=RATE,
    )


@pytest.mark.unit
def test_collector_joins_chunks_and_drops_an_utterance_too_long() -> None:
    collector = UtteranceCollector(max_samples=1000)
    assert collector.feed([VoiceActivity(True, 0), chunk(400, 0, False, 1)]) == []
    done = collector.feed([chunk(400, 1, False, 2), chunk(100, 2, True, 3), VoiceActivity(False, 0)])
    assert len(done) == 1
    pcm, rate = done[0]
    assert rate == RATE and pcm.tolist() == [1] * 400 + [2] * 400 + [3] * 100
    # 1200 samples: dropped whole, counted, and the next utterance starts clean
    assert collector.feed([chunk(600, 0, False), chunk(600, 1, False), chunk(10, 2, True)]) == []
    assert collector.too_long == 1
    assert [len(p) for p, _ in collector.feed([chunk(50, 0, True)])] == [50]
    # reset (the state changed mid-utterance) forgets a half-heard one
    collector.feed([chunk(300, 0, False)])
    collector.reset()
    assert [len(p) for p, _ in collector.feed([chunk(20, 0, True)])] == [20]
    assert UtteranceCollector().feed([chunk(int(MAX_UTTERANCE_S * RATE) + 1, 0, True)]) == []


class GatedRecognizer:
    """Blocks each decode until released, so the test controls what is waiting (no sleeps)."""

    def __init__(self) -> None:
        self.started = threading.Semaphore(0)
        self.release = threading.Semaphore(0)
        self.heard: list[int] = []

    def __call__(self, pcm: Int16Array, rate: int) -> WakeResult:
        self.started.release()
        self.release.acquire()
        if int(pcm[0]) < 0:
            raise RuntimeError("decoder broke")
        self.heard.append(int(pcm[0]))
        return WakeResult(str(int(pcm[0])), wake=False)


@pytest.mark.unit
def test_worker_keeps_one_utterance_waiting_and_survives_errors() -> None:
    gate = GatedRecognizer()
    done: list[tuple[int, str]] = []
    errors: list[tuple[int, str]] = []
    worker = WakeWorker(
        gate, lambda tag, r: done.append((tag, r.text)), lambda tag, e: errors.append((tag, str(e)))
    )
    try:
        worker.submit(1, np.array([1], dtype=np.int16), RATE)
        assert gate.started.acquire(timeout=10)  # decoding 1
        worker.submit(2, np.array([2], dtype=np.int16), RATE)
        worker.submit(3, np.array([-3], dtype=np.int16), RATE)  # replaces 2, which is dropped
        worker.submit(4, np.array([4], dtype=np.int16), RATE)  # replaces 3
        worker.submit(5, np.array([-5], dtype=np.int16), RATE)  # replaces 4
        gate.release.release()
        assert gate.started.acquire(timeout=10)  # decoding 5, which fails
        gate.release.release()
        wait_for(lambda: errors, what="the error to be reported")
        worker.submit(6, np.array([6], dtype=np.int16), RATE)  # the worker goes on after an error
        assert gate.started.acquire(timeout=10)
        gate.release.release()
        wait_for(lambda: len(done) == 2, what="the utterance after the error")
    finally:
        worker.close()
    assert done == [(1, "1"), (6, "6")]
    assert errors == [(5, "decoder broke")]
    assert (worker.decoded, worker.dropped, worker.errors) == (2, 3, 1)


@pytest.mark.unit
def test_spoken_wake_is_a_parameter_on_by_default_and_in_the_config_file() -> None:
    assert VadConfig().spoken_wake is True
    path = Path(__file__).resolve().parents[2] / "config" / "vad.yaml"
    shown = yaml.safe_load(path.read_text())["/**/silero_vad_node"]["ros__parameters"]
    defaults = {f.name for f in dataclasses.fields(VadConfig)}
    assert shown["spoken_wake"] is True and set(shown) == defaults
