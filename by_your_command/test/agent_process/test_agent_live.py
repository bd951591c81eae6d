"""The OpenAI Realtime provider against the real API (marker `live`: skipped without OPENAI_API_KEY,
never run in CI). No ROS: one text turn and one short voice turn (espeak-ng speech, resampled to the
session's 24 kHz) through the provider, each answered with words, audio and billed usage.

    OPENAI_API_KEY=sk-... scripts/run_tests.sh by_your_command/test/agent_process/test_agent_live.py
    BYC_LIVE_OPENAI_MODEL=gpt-realtime-2.1 ...   # default: the cheaper gpt-realtime-2.1-mini

It costs a few cents. Against `byc emulate openai` (OPENAI_BASE_URL=http://127.0.0.1:PORT/v1 and
any key) it checks the test itself without spending.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import subprocess
from collections.abc import Awaitable
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
from by_your_command.agents.provider import SessionSetup
from by_your_command.agents.providers.openai_realtime import OpenAIRealtimeConfig, OpenAIRealtimeProvider
from by_your_command.audio.pcm import StreamResampler, read_wav, to_mono

pytestmark = [
    pytest.mark.live,
    pytest.mark.timeout(120),
    pytest.mark.skipif(not os.environ.get("OPENAI_API_KEY"), reason="needs OPENAI_API_KEY"),
]

MODEL = os.environ.get("BYC_LIVE_OPENAI_MODEL", "gpt-realtime-2.1-mini")
SETUP = SessionSetup(instructions="You are a test robot. Answer every question in at most five words.")
REPLY_DEADLINE_S = 60.0


async def reply(provider: OpenAIRealtimeProvider) -> list[ProviderEvent]:
    """The events of one reply, up to and including its response.done."""
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
    assert words and words[0].strip(), "no words in the reply"
    assert done.usage.output_tokens > 0 and done.usage.input_tokens > 0
    return done.usage


def espeak(text: str, path: Path) -> np.ndarray:
    """Synthetic speech at 24 kHz (espeak-ng writes 22.05 kHz)."""
    subprocess.run(["espeak-ng", "-v", "en-us", "-s", "150", "-w", str(path), text], check=True)
    samples, rate, channels = read_wav(path)
    resampler = StreamResampler(rate, 24000)
    mono = to_mono(samples, channels)
    return np.concatenate([resampler.push(mono), resampler.flush()]).astype(np.int16)


def test_a_text_turn_and_a_voice_turn_against_the_real_api(tmp_path: Path) -> None:
    if shutil.which("espeak-ng") is None:
        pytest.skip("espeak-ng is needed for the voice turn (apt-get install espeak-ng)")
    speech = espeak("What colour is the sky on a clear day?", tmp_path / "question.wav")

    async def main() -> None:
        provider = OpenAIRealtimeProvider(OpenAIRealtimeConfig(model=MODEL))
        try:
            await provider.connect(SETUP)
            check_spoken_reply(await _turn(provider, provider.send_text("Say hello to the robot team.")))
            # A voice turn: 100 ms appends as our VAD streams them, then the commit and the reply.
            pcm = speech.astype("<i2").tobytes()
            step = 2 * 2400
            for start in range(0, len(pcm), step):
                await provider.send_audio(pcm[start : start + step])
            usage = check_spoken_reply(await _turn(provider, provider.end_of_turn()))
            assert usage.input_audio_tokens > 0, "the user's audio was not billed: was it heard?"
        finally:
            await provider.close()

    asyncio.run(main())


async def _turn(provider: OpenAIRealtimeProvider, sending: Awaitable[None]) -> list[ProviderEvent]:
    """Send (`sending`) while already reading, so no early event is missed."""
    reading = asyncio.ensure_future(reply(provider))
    await sending
    return await reading
