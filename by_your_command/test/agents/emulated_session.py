"""What the cloud provider tests share (OpenAI Realtime, GPT-Live, Gemini Live): one provider
connected to a fresh emulator for a test body, and reading the provider's events."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Awaitable, Callable, Coroutine
from typing import Any, Protocol, TypeVar

from by_your_command.agents.events import ProviderEvent, ResponseDone
from by_your_command.agents.provider import Provider, SessionSetup
from by_your_command.emulators.openai_gateway import GatewayServer

SESSION_TIMEOUT_S = 30.0  # a hung session fails its test instead of the whole run's timeout


class Emulator(Protocol):
    async def stop(self) -> None: ...


E = TypeVar("E", bound=Emulator)
P = TypeVar("P", bound=Provider)


def run_session(
    start_emulator: Callable[[], Awaitable[E]],
    make_provider: Callable[[E], P],
    body: Callable[[E, P], Coroutine[Any, Any, None]],
    setup: SessionSetup,
) -> None:
    """Start the emulator, connect the provider to it with `setup`, run `body`; close both after."""

    async def main() -> None:
        emulator = await start_emulator()
        provider = make_provider(emulator)
        try:
            await provider.connect(setup)
            await body(emulator, provider)
        finally:
            await provider.close()
            await emulator.stop()

    asyncio.run(asyncio.wait_for(main(), SESSION_TIMEOUT_S))


async def take_until(
    events: AsyncIterator[ProviderEvent], done: Callable[[ProviderEvent], bool]
) -> list[ProviderEvent]:
    """Events up to and with the first that is `done`; failing if the stream ends before it."""
    taken: list[ProviderEvent] = []
    async for event in events:
        taken.append(event)
        if done(event):
            return taken
    raise AssertionError(f"events ended before the expected one; got {taken}")


def is_done(event: ProviderEvent) -> bool:
    return isinstance(event, ResponseDone)


def sent(emulator: GatewayServer, kind: str) -> list[dict[str, Any]]:
    """The client events of this type an OpenAI emulator (Realtime or GPT-Live) received, in order."""
    return [record.event for record in emulator.received if record.event["type"] == kind]
