"""The OpenAI Realtime session behind the `Provider` protocol, on the official SDK (GA interface only).

Turns come from our own VAD: `turn_detection` is null, the end of an utterance commits the input
buffer and asks for a reply. The session declares 24 kHz PCM both ways; `input_sample_rate` tells
the runtime to resample the 16 kHz microphone (audio.pcm.StreamResampler) before `send_audio`.
The endpoint comes from config (base_url / websocket_base_url) or the SDK's OPENAI_BASE_URL, so
Azure, proxies and `byc emulate openai` work; the key from the constructor or OPENAI_API_KEY, and
it is never logged.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import logging
import uuid
from collections import deque
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass
from typing import Literal

from openai import AsyncOpenAI
from openai.resources.realtime.realtime import AsyncRealtimeConnection
from openai.types.realtime import (
    RealtimeAudioConfigParam,
    RealtimeErrorEvent,
    RealtimeSessionCreateRequestParam,
    RealtimeToolsConfigParam,
    ResponseDoneEvent,
    SessionUpdatedEvent,
)
from websockets.exceptions import ConnectionClosed

from by_your_command.agents.events import ProviderError, ProviderEvent
from by_your_command.agents.provider import (
    HistoryTurn,
    ProviderClosed,
    ProviderFailure,
    Role,
    SessionSetup,
    ToolResult,
    ToolSpec,
)
from by_your_command.agents.providers.event_stream import EventStream
from by_your_command.agents.providers.failures import closing_on_failure
from by_your_command.agents.providers.openai_common.connection import (
    open_connection,
    release,
    sdk_client,
    websocket_options,
)
from by_your_command.agents.providers.openai_realtime.errors import handshake_error, provider_error
from by_your_command.agents.providers.openai_realtime.events import BYTES_PER_MS, SAMPLE_RATE, EventTranslator
from by_your_command.agents.providers.session_guards import check_whole_samples, open_session
from by_your_command.net.quiet_websockets import quiet_websocket_logger

log = logging.getLogger(__name__)

_SESSION = "the OpenAI Realtime session"  # as errors name it
MIN_COMMIT_MS = 100  # the server refuses shorter commits (input_audio_buffer_commit_empty)
MAX_SESSION_S = 3600.0  # GA sessions end after 60 minutes (session_expired)
MAX_IMAGE_BYTES = 10 * 1024 * 1024  # an event carries at most 15 MiB, base64 inflates by 4/3
_QUIET_WEBSOCKET_LOG = quiet_websocket_logger(__name__)


@dataclass(frozen=True)
class OpenAIRealtimeConfig:
    model: str = "gpt-realtime-2.1"
    voice: str = "marin"
    transcription_model: str = "gpt-realtime-whisper"  # user transcripts; "" turns them off
    transcription_language: str = ""  # ISO-639-1 hint, "" = detect
    noise_reduction: Literal["", "near_field", "far_field"] = "far_field"  # a robot's mic is far
    image_detail: Literal["auto", "low", "high"] = "low"
    max_images_in_context: int = 1  # older camera frames are deleted: each costs tokens every turn
    max_output_tokens: int | None = None
    base_url: str = ""  # "" = the SDK's OPENAI_BASE_URL or api.openai.com
    websocket_base_url: str = ""  # wins over base_url; must end in /v1 (the SDK appends /realtime)
    extra_headers: tuple[tuple[str, str], ...] = ()  # e.g. OpenAI-Project, proxy auth
    event_queue_size: int = 1024  # events the runtime has not read yet; the socket waits beyond it

    def __post_init__(self) -> None:
        if not self.model or not self.voice:
            raise ValueError("model and voice must not be empty")
        if self.max_images_in_context < 0 or self.event_queue_size < 1:
            raise ValueError("max_images_in_context must be >= 0 and event_queue_size >= 1")


class OpenAIRealtimeProvider:
    """One OpenAI Realtime session (see agents/provider.py for the contract)."""

    name = "openai_realtime"
    input_sample_rate = SAMPLE_RATE
    max_session_s = MAX_SESSION_S

    def __init__(self, config: OpenAIRealtimeConfig | None = None, api_key: str | None = None) -> None:
        self.config = config or OpenAIRealtimeConfig()
        self._api_key = api_key
        self._connection: AsyncRealtimeConnection | None = None
        self._events = EventStream(self.config.event_queue_size)
        self._translator = EventTranslator()
        self._reader: asyncio.Task[None] | None = None
        self._closed = False
        self._buffered_bytes = 0  # input audio appended since the last commit
        self._reply_requested = False  # a response.create is in flight or its response is running
        self._reply_deferred = False  # another reply was asked for meanwhile: create it at response.done
        self._create_event_id = ""  # event_id of the last response.create we sent
        self._images: deque[str] = deque()  # ids of camera-frame items still in the conversation
        self._client: AsyncOpenAI | None = None

    # ---- session ----------------------------------------------------------------------------
    async def connect(self, setup: SessionSetup) -> None:
        if self._connection is not None or self._closed:
            raise ProviderClosed("a provider is one session: build a new one to reconnect")
        config = self.config
        self._client = client = sdk_client(self._api_key, config.base_url, config.websocket_base_url)
        manager = client.realtime.connect(
            model=config.model,
            extra_headers=dict(config.extra_headers),
            websocket_connection_options=websocket_options(_QUIET_WEBSOCKET_LOG),
        )
        connection = await open_connection(manager, handshake_error)
        self._connection = connection
        try:
            await self._configure(connection, setup)
        except BaseException:
            self._closed = True
            with contextlib.suppress(Exception):
                await connection.close()
            raise
        self._reader = asyncio.ensure_future(self._read(connection))

    async def _configure(self, connection: AsyncRealtimeConnection, setup: SessionSetup) -> None:
        """session.update, then wait for session.updated: a refused config is a fatal config error."""
        with contextlib.suppress(ConnectionClosed):  # a refusal may already be on its way: read it
            await connection.session.update(session=self._session_config(setup))
        while True:
            try:
                event = await connection.recv()
            except ConnectionClosed as closed:
                reason = closed.rcvd.reason if closed.rcvd else ""
                code = "beta_api_shape_disabled" if "beta_api_shape_disabled" in reason else ""
                mapped = provider_error(code, reason) if code else None
                if mapped is not None:
                    raise ProviderFailure(mapped) from None
                raise ProviderClosed(
                    f"the server closed the session while it was set up ({reason})"
                ) from None
            if isinstance(event, SessionUpdatedEvent):
                break
            if isinstance(event, RealtimeErrorEvent):
                mapped = provider_error(event.error.code, event.error.message)
                if mapped is not None:
                    fatal = mapped.retry_after_s is None  # a refused session config will not fix itself
                    raise ProviderFailure(
                        ProviderError(mapped.code, mapped.message, fatal, mapped.retry_after_s)
                    )
        for turn in setup.history:
            await self._add_history(connection, turn)

    def _session_config(self, setup: SessionSetup) -> RealtimeSessionCreateRequestParam:
        config = self.config
        pcm: Literal["audio/pcm"] = "audio/pcm"
        audio: RealtimeAudioConfigParam = {
            "input": {"format": {"type": pcm, "rate": SAMPLE_RATE}, "turn_detection": None},
            "output": {"format": {"type": pcm, "rate": SAMPLE_RATE}, "voice": config.voice},
        }
        if config.transcription_model:
            audio["input"]["transcription"] = {"model": config.transcription_model}
            if config.transcription_language:
                audio["input"]["transcription"]["language"] = config.transcription_language
        if config.noise_reduction:
            audio["input"]["noise_reduction"] = {"type": config.noise_reduction}
        session: RealtimeSessionCreateRequestParam = {
            "type": "realtime",
            "model": config.model,
            "instructions": setup.instructions,
            "output_modalities": ["audio"] if setup.audio_out else ["text"],
            "audio": audio,
            "tools": _tools(setup.tools),
        }
        if config.max_output_tokens is not None:
            session["max_output_tokens"] = config.max_output_tokens
        return session

    @staticmethod
    async def _add_history(connection: AsyncRealtimeConnection, turn: HistoryTurn) -> None:
        if turn.role is Role.USER:
            await connection.conversation.item.create(
                item={
                    "type": "message",
                    "role": "user",
                    "content": [{"type": "input_text", "text": turn.text}],
                }
            )
        else:
            await connection.conversation.item.create(
                item={
                    "type": "message",
                    "role": "assistant",
                    "content": [{"type": "output_text", "text": turn.text}],
                }
            )

    async def close(self) -> None:
        self._closed = True
        connection, self._connection = self._connection, None
        await release(connection, self._reader, self._events, self._client)

    # ---- input ------------------------------------------------------------------------------
    def _live(self) -> AsyncRealtimeConnection:
        return open_session(self._closed, self._connection, _SESSION)

    async def send_audio(self, pcm: bytes) -> None:
        check_whole_samples(pcm)
        if not pcm:
            return
        connection = self._live()
        async with closing_on_failure(_SESSION):
            await connection.input_audio_buffer.append(audio=base64.b64encode(pcm).decode("ascii"))
        self._buffered_bytes += len(pcm)

    async def end_of_turn(self) -> None:
        connection = self._live()
        buffered_ms = self._buffered_bytes // BYTES_PER_MS
        if buffered_ms < MIN_COMMIT_MS:
            # The server would refuse the commit and then answer nothing in particular: say so instead.
            async with closing_on_failure(_SESSION):
                if self._buffered_bytes:
                    await connection.input_audio_buffer.clear()
            self._buffered_bytes = 0
            await self._events.put(
                ProviderError(
                    "input_audio_buffer_commit_empty",
                    f"utterance of {buffered_ms} ms not sent: the API needs at least {MIN_COMMIT_MS} ms",
                    refuses_turn=True,
                )
            )
            return
        async with closing_on_failure(_SESSION):
            await connection.input_audio_buffer.commit()
        self._buffered_bytes = 0
        await self._request_reply()

    async def send_text(self, text: str) -> None:
        connection = self._live()
        async with closing_on_failure(_SESSION):
            await connection.conversation.item.create(
                item={"type": "message", "role": "user", "content": [{"type": "input_text", "text": text}]}
            )
        await self._request_reply()

    async def add_context(self, text: str) -> None:
        connection = self._live()
        async with closing_on_failure(_SESSION):
            await connection.conversation.item.create(
                item={"type": "message", "role": "user", "content": [{"type": "input_text", "text": text}]}
            )

    async def send_image(self, jpeg: bytes) -> None:
        if not jpeg.startswith(b"\xff\xd8") or len(jpeg) > MAX_IMAGE_BYTES:
            raise ValueError(f"not a JPEG of at most {MAX_IMAGE_BYTES} bytes ({len(jpeg)} bytes)")
        connection = self._live()
        item_id = f"img_{uuid.uuid4().hex[:24]}"  # our own id, so the frame can be deleted later
        url = "data:image/jpeg;base64," + base64.b64encode(jpeg).decode("ascii")
        async with closing_on_failure(_SESSION):
            await connection.conversation.item.create(
                item={
                    "id": item_id,
                    "type": "message",
                    "role": "user",
                    "content": [
                        {"type": "input_image", "image_url": url, "detail": self.config.image_detail}
                    ],
                }
            )
            self._images.append(item_id)
            while len(self._images) > self.config.max_images_in_context:
                await connection.conversation.item.delete(item_id=self._images.popleft())

    async def send_tool_results(self, results: Sequence[ToolResult]) -> None:
        """Every output first, then one response.create: one reply for all of a response's calls."""
        connection = self._live()
        async with closing_on_failure(_SESSION):
            for result in results:
                await connection.conversation.item.create(
                    item={"type": "function_call_output", "call_id": result.call_id, "output": result.output}
                )
        if results:
            await self._request_reply()

    async def send_tool_progress(self, call_id: str, text: str) -> None:
        """Realtime has no partial function output: the progress is a note in the conversation
        (no response.create); the call's function_call_output comes when it ends."""
        await self.add_context(text)

    async def interrupt(self, response_id: str, item_id: str, played_ms: int) -> None:
        connection = self._live()
        async with closing_on_failure(_SESSION):
            # Always sent: the reply may have ended on the server already, and the resulting
            # response_cancel_not_active is harmless (dropped by the translator). No id: cancel
            # whatever runs (a reply that has not said anything yet has no id the runtime knows).
            cancelled = response_id or self._translator.active_response
            if cancelled:
                self._translator.mark_cancelled(cancelled)
            if response_id:
                await connection.response.cancel(response_id=response_id)
            else:
                await connection.response.cancel()
            received_ms = self._translator.audio_received_ms(item_id) if item_id else 0
            end_ms = min(max(played_ms, 0), received_ms)  # beyond the audio received is a fatal error
            if end_ms < played_ms:
                log.debug("truncate of %s clamped from %d to %d ms", item_id, played_ms, end_ms)
            if end_ms > 0:
                await connection.conversation.item.truncate(
                    item_id=item_id, content_index=0, audio_end_ms=end_ms
                )

    async def _request_reply(self) -> None:
        """response.create, or later: one reply at a time per conversation (the server's rule)."""
        if self._reply_requested:
            self._reply_deferred = True
            return
        self._reply_requested = True
        self._create_event_id = f"evt_create_{uuid.uuid4().hex[:16]}"  # errors name the event they refuse
        async with closing_on_failure(_SESSION):
            await self._live().response.create(event_id=self._create_event_id)

    # ---- output -----------------------------------------------------------------------------
    def events(self) -> AsyncIterator[ProviderEvent]:
        return self._events.__aiter__()

    async def _read(self, connection: AsyncRealtimeConnection) -> None:
        why = "connection_lost"  # what a reply cut by the end of the connection reports
        try:
            while True:
                try:
                    event = connection.parse_event(await connection.recv_bytes())
                except ConnectionClosed as closed:
                    why = f"connection lost: {closed}"  # with the close code and the server's reason
                    break
                except ValueError as error:  # not JSON / not an event: report, keep the session
                    await self._events.put(
                        ProviderError("invalid_server_event", f"unreadable event: {error}")
                    )
                    continue
                for translated in self._translator.translate(event):
                    await self._events.put(translated)
                await self._after(event)
        except ProviderClosed:
            pass
        finally:
            self._closed = True
            for translated in self._translator.connection_lost(why):
                self._events.put_last(translated)
            self._events.end()

    async def _after(self, event: object) -> None:
        """Bookkeeping for reply requests: a deferred reply is created when the running one is done."""
        if isinstance(event, ResponseDoneEvent) and event.response.conversation_id is not None:
            self._reply_requested = False
            if self._reply_deferred:
                self._reply_deferred = False
                await self._request_reply()
        elif isinstance(event, RealtimeErrorEvent) and event.error.event_id == self._create_event_id:
            if event.error.code == "conversation_already_has_active_response":
                self._reply_deferred = True  # another reply is running: ask again when it is done
            else:  # refused: no response.done will come, so do not wait for one
                self._reply_requested = False
                if self._reply_deferred:
                    self._reply_deferred = False
                    await self._request_reply()


def _tools(tools: Sequence[ToolSpec]) -> RealtimeToolsConfigParam:
    return [
        {
            "type": "function",
            "name": tool.name,
            "description": tool.description,
            "parameters": tool.parameters,
        }
        for tool in tools
    ]
