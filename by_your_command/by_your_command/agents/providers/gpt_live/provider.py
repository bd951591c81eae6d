"""The OpenAI GPT-Live session behind the `Provider` protocol, on the official SDK (`client.live`).

GPT-Live is full duplex: one audio stream each way, and the model decides when to speak, when to
delegate work and when to yield to the user (`duplex`: the runtime does not judge barge-ins, it
cuts the player when the model yields). So:

- the input is one stream in real time (input.InputClock): each utterance's audio as it
  comes, and silence in between, appended every `input_tick_ms`; `end_of_turn` only marks the
  utterance's end (there is no commit or response.create: the model hears the user stop).
- replies are made up by `LiveTranslator` (no response ids, no reply end on the wire); a reply the
  user spoke over that goes quiet is an `Interrupted` (the model yielded).
- `interrupt` cannot cancel: the model hears the user over the same stream and stops by itself
  (or talks on). It marks the reply cut, so its audio is dropped and its end says so.
- robot tools: client delegation (`session.delegation.created`) names no function, so it is a
  `ToolCall` of `delegation_tool` with the user's words as the command (events.py). The
  result goes back as `session.commentary.append` for that delegation (the model speaks it),
  progress as `session.thinking.append` (silent).
- `send_text` and `add_context` are `session.instructions.append`: client delegation has no user
  text item (response.item.create needs Responses delegation). `send_image` is refused: GPT-Live
  takes no images.
- muting: `mute()` / `unmute()` (`session.input_audio.mute|unmute`; muted input reaches the model
  as silence and is still billed).

Billing is per second of open session (silence and mute included): `billed_seconds` is the
server's cumulative count. The endpoint comes from config (base_url / websocket_base_url) or the
SDK's OPENAI_BASE_URL, so `byc emulate gpt-live` works; the key from the constructor or
OPENAI_API_KEY, and it is never logged.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import logging
import uuid
from collections import Counter
from collections.abc import AsyncIterator, Sequence

from openai import AsyncOpenAI
from openai.resources.live.live import AsyncLiveConnection
from openai.types.live import ErrorEvent, SessionClosedEvent, SessionStartedEvent
from openai.types.live.client_delegation_param import ClientDelegationParam
from openai.types.live.initial_item_param import InitialItemParam
from openai.types.live.session_config_param import SessionConfigParam
from websockets.exceptions import ConnectionClosed

from by_your_command.agents.events import ProviderError, ProviderEvent
from by_your_command.agents.provider import (
    HistoryTurn,
    ProviderClosed,
    ProviderFailure,
    Role,
    SessionSetup,
    ToolResult,
)
from by_your_command.agents.providers.event_stream import EventStream
from by_your_command.agents.providers.failures import closing_on_failure
from by_your_command.agents.providers.gpt_live.config import GptLiveConfig
from by_your_command.agents.providers.gpt_live.errors import handshake_error, start_refusal
from by_your_command.agents.providers.gpt_live.events import (
    LiveTranslator,
    UnreadableEvent,
    parse_server_event,
)
from by_your_command.agents.providers.gpt_live.input import InputClock
from by_your_command.agents.providers.openai_common.connection import (
    open_connection,
    release,
    sdk_client,
    websocket_options,
)
from by_your_command.agents.providers.session_guards import check_whole_samples, open_session
from by_your_command.net.quiet_websockets import quiet_websocket_logger

log = logging.getLogger(__name__)

_SESSION = "the GPT-Live session"  # as errors name it
MAX_APPEND_BYTES = 1024 * 1024  # one input_audio.append: longer audio goes in several
_QUIET_WEBSOCKET_LOG = quiet_websocket_logger(__name__)


class GptLiveProvider:
    """One GPT-Live session (see agents/provider.py for the contract)."""

    name = "gpt_live"
    accepts_images = False  # for a runtime that asks before sending camera frames
    duplex = True  # the model hears the user over its voice and yields by itself (runtime: no barge-in judge)

    def __init__(self, config: GptLiveConfig | None = None, api_key: str | None = None) -> None:
        self.config = config or GptLiveConfig()
        self.input_sample_rate: int = self.config.sample_rate
        self.max_session_s = self.config.max_session_s
        self._api_key = api_key
        self._client: AsyncOpenAI | None = None
        self._connection: AsyncLiveConnection | None = None
        self._events = EventStream(self.config.event_queue_size)
        self._translator = LiveTranslator(
            self.config.sample_rate,
            self.config.reply_end_gap_ms / 1000,
            self.config.delegation_tool,
            yield_gap_s=self.config.yield_gap_ms / 1000,
        )
        self._input = InputClock(self.config.sample_rate, self.config.max_catch_up_ms / 1000)
        self.silence_skipped_s = 0.0  # behind real time after a stall, beyond max_catch_up (not sent)
        self._reader: asyncio.Task[None] | None = None
        self._silence: asyncio.Task[None] | None = None
        self._input_order = asyncio.Lock()  # speech and silence appends, one at a time, in order
        self._session_closed = asyncio.Event()  # session.closed came: the server finalized
        self._closed = False
        self.muted = False
        self.session_id = ""

    @property
    def billed_seconds(self) -> float:
        """The server's cumulative seconds of this session (billed per second, silence included)."""
        return self._translator.billed_seconds

    @property
    def finalized(self) -> bool:
        """The server confirmed the session's end (session.closed): its billing stopped there."""
        return self._session_closed.is_set()

    @property
    def ignored_events(self) -> Counter[str]:
        """Server events read and dropped (not used by this provider), by type."""
        return Counter(self._translator.ignored)

    # ---- session ----------------------------------------------------------------------------
    async def connect(self, setup: SessionSetup) -> None:
        if self._connection is not None or self._closed:
            raise ProviderClosed("a provider is one session: build a new one to reconnect")
        config = self.config
        self._translator.text_replies = not setup.audio_out
        self._client = client = sdk_client(self._api_key, config.base_url, config.websocket_base_url)
        # No on_reconnecting: the SDK does not reconnect by itself; the runtime opens a new session.
        manager = client.live.connect(
            extra_headers=dict(config.extra_headers),
            websocket_connection_options=websocket_options(_QUIET_WEBSOCKET_LOG),
        )
        connection = await open_connection(manager, handshake_error)
        self._connection = connection
        try:
            await self._start(connection, setup)
        except BaseException:
            self._closed = True
            with contextlib.suppress(Exception):
                await connection.close()
            raise
        self._reader = asyncio.ensure_future(self._read(connection))
        self._silence = asyncio.ensure_future(self._keep_input_live(connection))

    async def _start(self, connection: AsyncLiveConnection, setup: SessionSetup) -> None:
        """session.start, then wait for session.started: a refused start is a fatal config error."""
        start_id = f"evt_start_{uuid.uuid4().hex[:16]}"
        with contextlib.suppress(ConnectionClosed):  # a refusal may already be on its way: read it
            await connection.session.start(session=self._session_config(setup), event_id=start_id)
        while True:
            try:
                raw = await connection.recv_bytes()
            except ConnectionClosed as closed:
                reason = closed.rcvd.reason if closed.rcvd else ""
                raise ProviderClosed(f"the server closed the session while it started ({reason})") from None
            try:
                event = parse_server_event(raw)
            except UnreadableEvent:
                continue
            if isinstance(event, SessionStartedEvent):
                self.session_id = event.session.id
                return
            if isinstance(event, ErrorEvent):
                raise ProviderFailure(start_refusal(event.error.code, event.error.message))

    def _session_config(self, setup: SessionSetup) -> SessionConfigParam:
        config = self.config
        delegation: ClientDelegationParam = {"type": "client"}  # our code (the robot) does the work
        if config.acknowledgement_delay_ms is not None:
            delegation["acknowledgement_delay_ms"] = config.acknowledgement_delay_ms
        session: SessionConfigParam = {
            "model": config.model,
            "audio": {
                "format": {"type": "audio/pcm", "rate": config.sample_rate},
                "output": {"voice": config.voice},
            },
            "delegation": delegation,
        }
        if setup.instructions.strip():
            session["instructions"] = setup.instructions
        history = _history(setup.history, config.max_history_messages, config.max_history_chars)
        if history:
            session["input"] = history
        if config.safety_identifier:
            session["safety_identifier"] = config.safety_identifier
        return session

    async def close(self) -> None:
        """session.close, then wait (closed_wait_s at most) for session.closed: the server's final
        usage, and a session it confirms finalized (billing stops). Then the socket goes."""
        if self._closed and self._connection is None:
            self._events.end()
            return
        self._closed = True
        connection, self._connection = self._connection, None
        if self._silence is not None:
            self._silence.cancel()
            await asyncio.gather(self._silence, return_exceptions=True)
        try:
            if connection is not None and self._reader is not None and not self._reader.done():
                with contextlib.suppress(Exception):
                    await connection.session.close()
                    await asyncio.wait_for(self._session_closed.wait(), self.config.closed_wait_s)
        finally:
            await release(connection, self._reader, self._events, self._client)

    # ---- input ------------------------------------------------------------------------------
    def _live(self) -> AsyncLiveConnection:
        return open_session(self._closed, self._connection, _SESSION)

    async def send_audio(self, pcm: bytes) -> None:
        check_whole_samples(pcm)
        if not pcm:
            return
        connection = self._live()
        now = asyncio.get_running_loop().time()
        starts = not self._input.in_utterance
        async with self._input_order:
            self._input.in_utterance = True  # no silence spliced into the speech from here
            await self._append(connection, pcm)
            self._input.speech_sent(now)
        if not self.muted:  # muted speech never reaches the model: it cannot yield to it
            self._translator.user_speech(now, starts=starts)

    async def end_of_turn(self) -> None:
        """The utterance ended: silence follows at real time (`_keep_input_live`), and the model
        hears the user stop (see the module docstring)."""
        self._live()
        self._input.in_utterance = False

    async def _keep_input_live(self, connection: AsyncLiveConnection) -> None:
        """Silence between utterances, at real time, for the session's life. A failed append ends
        the connection like any other (the reader reports it)."""
        loop = asyncio.get_running_loop()
        self._input.start(loop.time())
        tick = self.config.input_tick_ms / 1000
        try:
            while not self._closed:
                await asyncio.sleep(tick)
                async with self._input_order:  # decided and sent before any speech that follows
                    plan = self._input.silence_due(loop.time())
                    if plan.skipped:
                        self.silence_skipped_s += plan.skipped / self.config.sample_rate
                    if plan.samples and not self._closed:
                        await self._append(connection, bytes(2 * plan.samples))
        except ProviderClosed:
            return  # the connection is gone: the reader ends the session

    async def _append(self, connection: AsyncLiveConnection, pcm: bytes) -> None:
        async with closing_on_failure(_SESSION):
            for offset in range(0, len(pcm), MAX_APPEND_BYTES):
                chunk = pcm[offset : offset + MAX_APPEND_BYTES]
                await connection.session.input_audio.append(audio=base64.b64encode(chunk).decode("ascii"))

    async def send_text(self, text: str) -> None:
        """A typed turn as an instruction to answer it: client delegation has no user text item."""
        await self._instruct(f"The user typed this message; answer it aloud: {text}")

    async def add_context(self, text: str) -> None:
        await self._instruct(text)

    async def _instruct(self, text: str) -> None:
        connection = self._live()
        async with closing_on_failure(_SESSION):
            await connection.session.instructions.append(content=self._bounded(text), delegation_id=None)

    async def send_image(self, jpeg: bytes) -> None:
        raise ValueError("GPT-Live takes no images: use the openai or gemini provider for a camera agent")

    async def send_tool_results(self, results: Sequence[ToolResult]) -> None:
        """Each result as commentary for its delegation: the model tells the user (it may word it)."""
        connection = self._live()
        async with closing_on_failure(_SESSION):
            for result in results:
                await connection.session.commentary.append(
                    content=self._bounded(f"Result of the delegated task: {result.output}"),
                    delegation_id=result.call_id,
                )

    async def send_tool_progress(self, call_id: str, text: str) -> None:
        """Progress as thinking for the delegation: the model knows it, says nothing unasked."""
        connection = self._live()
        async with closing_on_failure(_SESSION):
            await connection.session.thinking.append(content=self._bounded(text), delegation_id=call_id)

    async def interrupt(self, response_id: str, item_id: str, played_ms: int) -> None:
        """No cancel or truncate exists: the model decides barge-in by hearing the user. Its reply
        is marked cut here (audio dropped; its end reports cancelled)."""
        self._live()
        self._translator.cut(response_id)

    async def mute(self) -> None:
        """The model hears silence until `unmute` (the session, and its billing, go on)."""
        connection = self._live()
        async with closing_on_failure(_SESSION):
            await connection.session.input_audio.mute()
        self.muted = True

    async def unmute(self) -> None:
        connection = self._live()
        async with closing_on_failure(_SESSION):
            await connection.session.input_audio.unmute()
        self.muted = False

    def _bounded(self, text: str) -> str:
        limit = self.config.max_append_chars
        return text if len(text) <= limit else text[: limit - 1] + "…"

    # ---- output -----------------------------------------------------------------------------
    def events(self) -> AsyncIterator[ProviderEvent]:
        return self._events.__aiter__()

    async def _read(self, connection: AsyncLiveConnection) -> None:
        """Server events in order; between them, the translator's quiet timer ends replies. The
        receive is one task kept across timeouts (never cancelled mid-frame)."""
        loop = asyncio.get_running_loop()
        translator = self._translator
        why = "connection_lost"  # what a reply cut by the end of the connection reports
        receive: asyncio.Future[bytes] | None = None
        try:
            while True:
                if receive is None:
                    receive = asyncio.ensure_future(connection.recv_bytes())
                deadline = translator.deadline()
                timeout = None if deadline is None else max(0.0, deadline - loop.time())
                await asyncio.wait({receive}, timeout=timeout)
                if receive.done():
                    done, receive = receive, None
                    try:
                        raw = done.result()
                    except ConnectionClosed as closed:
                        why = f"connection lost: {closed}"  # with the close code and the server's reason
                        break
                    await self._translate(raw, loop.time())
                for event in translator.tick(loop.time()):
                    await self._events.put(event)
        finally:
            if receive is not None:
                receive.cancel()
            self._closed = True
            for event in translator.connection_lost(why):
                self._events.put_last(event)
            self._events.end()

    async def _translate(self, raw: bytes, now: float) -> None:
        try:
            event = parse_server_event(raw)
        except UnreadableEvent as error:  # report, keep the session
            await self._events.put(ProviderError("invalid_server_event", f"unreadable event: {error}"))
            return
        if isinstance(event, SessionClosedEvent):
            self._session_closed.set()
        for translated in self._translator.translate(event, now):
            await self._events.put(translated)


def _history(turns: Sequence[HistoryTurn], max_messages: int, max_chars: int) -> list[InitialItemParam]:
    """The newest turns that fit the documented limits, oldest first, one text part each."""
    kept: list[InitialItemParam] = []
    used = 0
    for turn in reversed(turns):
        text = turn.text.strip()
        if not text:
            continue
        if len(kept) >= max_messages or used + len(text) > max_chars:
            break
        used += len(text)
        if turn.role is Role.USER:
            kept.append(
                {"type": "message", "role": "user", "content": [{"type": "input_text", "text": text}]}
            )
        else:
            kept.append(
                {"type": "message", "role": "assistant", "content": [{"type": "output_text", "text": text}]}
            )
    kept.reverse()
    return kept
