"""The cloud providers against their real APIs (marker `live`: each skipped without its key, never
run in CI). No ROS: one text turn and one short voice turn (espeak-ng speech at the provider's input
rate: OpenAI 24 kHz; Gemini 16 kHz, bracketed by activityStart / activityEnd as our VAD does)
through the provider on its official SDK, each answered with words, 24 kHz audio and billed usage.

    OPENAI_API_KEY=sk-... scripts/run_tests.sh by_your_command/test/agent_process/test_agent_live.py -k openai
    GEMINI_API_KEY=... scripts/run_tests.sh by_your_command/test/agent_process/test_agent_live.py -k gemini
    BYC_LIVE_OPENAI_MODEL=gpt-realtime-2.1 ...   # default: the cheaper gpt-realtime-2.1-mini
    BYC_LIVE_GEMINI_MODEL=gemini-3.8-live ...    # default: the provider's default model

OpenAI costs a few cents, Gemini a fraction of a cent. Against the emulators it checks the test
itself without spending: `byc emulate openai` (OPENAI_BASE_URL=http://127.0.0.1:PORT/v1 and any
key); `byc emulate gemini` (GOOGLE_GEMINI_BASE_URL=<its base URL>, SSL_CERT_FILE=<its certificate>,
any key).
"""

from __future__ import annotations

import asyncio
import os
import shutil
import subprocess
from collections.abc import Awaitable, Callable
from pathlib import Path

import numpy as np
import pytest

from by_your_command.agents.events import (
    AssistantAudio,
    AssistantText,
    AssistantTranscript,
    ProviderError,
    ProviderEvent,
    ResponseDone,
    ResponseStatus,
    Usage,
)
from by_your_command.agents.provider import Provider, SessionSetup
from by_your_command.agents.providers.gemini_live.provider import GeminiLiveConfig, GeminiLiveProvider
from by_your_command.agents.providers.openai_realtime.provider import (
    OpenAIRealtimeConfig,
    OpenAIRealtimeProvider,
)
from by_your_command.audio.pcm import StreamResampler, read_wav, to_mono

pytestmark = [pytest.mark.live, pytest.mark.timeout(120)]

OPENAI_MODEL = os.environ.get("BYC_LIVE_OPENAI_MODEL", "gpt-realtime-2.1-mini")
GEMINI_MODEL = os.environ.get("BYC_LIVE_GEMINI_MODEL", GeminiLiveConfig().model)
GEMINI_KEY = os.environ.get("GOOGLE_API_KEY") or os.environ.get("GEMINI_API_KEY")  # google-genai's order
SETUP = SessionSetup(instructions="You are a test robot. Answer every question in at most five words.")
REPLY_DEADLINE_S = 60.0

PROVIDERS = [
    pytest.param(
        lambda: OpenAIRealtimeProvider(OpenAIRealtimeConfig(model=OPENAI_MODEL)),  # the SDK reads the key
        id="openai",
        marks=pytest.mark.skipif(not os.environ.get("OPENAI_API_KEY"), reason="needs OPENAI_API_KEY"),
    ),
    pytest.param(
        lambda: GeminiLiveProvider(GeminiLiveConfig(model=GEMINI_MODEL), api_key=GEMINI_KEY),
        id="gemini",
        marks=pytest.mark.skipif(not GEMINI_KEY, reason="needs GOOGLE_API_KEY or GEMINI_API_KEY"),
    ),
]


async def reply(provider: Provider) -> list[ProviderEvent]:
    """The events of one reply, up to and including its ResponseDone."""
    events: list[ProviderEvent] = []

    async def collect() -> None:
        async for event in provider.events():
            events.append(event)
            if isinstance(event, ResponseDone):
                return
            if isinstance(event, ProviderError):
                raise AssertionError(f"the API sent an error: {event.code}: {event.message}")

    await asyncio.wait_for(collect(), REPLY_DEADLINE_S)
    return events


def check_spoken_reply(events: list[ProviderEvent]) -> Usage:
    done = events[-1]
    assert isinstance(done, ResponseDone) and done.status is ResponseStatus.COMPLETED, done
    audio = b"".join(e.pcm for e in events if isinstance(e, AssistantAudio))
    words = [e.text for e in events if isinstance(e, (AssistantTranscript, AssistantText)) and e.final]
    assert len(audio) > 24000 * 2 // 10, "less than 100 ms of reply audio"
    assert {e.sample_rate for e in events if isinstance(e, AssistantAudio)} == {24000}
    assert words and words[0].strip(), "no words in the reply (for Gemini: its output transcription)"
    assert done.usage.output_tokens > 0 and done.usage.input_tokens > 0
    return done.usage


def espeak(text: str, path: Path, rate: int) -> np.ndarray:
    """Synthetic speech at `rate` (espeak-ng writes 22.05 kHz)."""
    subprocess.run(["espeak-ng", "-v", "en-us", "-s", "150", "-w", str(path), text], check=True)
    samples, wav_rate, channels = read_wav(path)
    resampler = StreamResampler(wav_rate, rate)
    mono = to_mono(samples, channels)
    return np.concatenate([resampler.push(mono), resampler.flush()]).astype(np.int16)


@pytest.mark.parametrize("make_provider", PROVIDERS)
def test_a_text_turn_and_a_voice_turn_against_the_real_api(
    make_provider: Callable[[], Provider], tmp_path: Path
) -> None:
    if shutil.which("espeak-ng") is None:
        pytest.skip("espeak-ng is needed for the voice turn (apt-get install espeak-ng)")

    async def main() -> None:
        provider = make_provider()
        rate = provider.input_sample_rate
        speech = espeak("What colour is the sky on a clear day?", tmp_path / "question.wav", rate)
        try:
            await provider.connect(SETUP)
            check_spoken_reply(await _turn(provider, provider.send_text("Say hello to the robot team.")))
            # A voice turn: 100 ms chunks as our VAD streams them (OpenAI appends them; Gemini's
            # first opens the activity), then end_of_turn (commit / activityEnd) and the reply.
            pcm = speech.astype("<i2").tobytes()
            step = 2 * rate // 10
            for start in range(0, len(pcm), step):
                await provider.send_audio(pcm[start : start + step])
            usage = check_spoken_reply(await _turn(provider, provider.end_of_turn()))
            assert usage.input_audio_tokens > 0, "the user's audio was not billed: was it heard?"
        finally:
            await provider.close()

    asyncio.run(main())


async def _turn(provider: Provider, sending: Awaitable[None]) -> list[ProviderEvent]:
    """Send (`sending`) while already reading, so no early event is missed."""
    reading = asyncio.ensure_future(reply(provider))
    await sending
    return await reading
