"""The Gemini Live session behind the `Provider` protocol, on the official google-genai SDK.

Turns come from our own VAD: automatic activity detection is disabled, each user turn's audio is
bracketed by activityStart / activityEnd, and no audio is sent outside them. 16 kHz PCM in, 24 kHz
out (the rate rides on every AssistantAudio). `interrupt` sends activityStart: Gemini has no
truncate, the server cuts its own history where it stopped generating.

The socket is read by one task for the whole session (`session.receive()` ends at every
turnComplete, so it runs in a `while True`): a resumption handle sent after a turnComplete is
never lost (python-genai#2527). Handles go to a `ResumptionHandles` store shared by the providers
of one agent; the next session resumes with the newest one only when it continues the same
conversation (`SessionSetup.conversation_id`, and a non-empty history), and falls back to a fresh
session plus text context when the server refuses the resume.

Endpoint, API version and CA file come from config, else the SDK's own environment variables
(GOOGLE_GEMINI_BASE_URL, GOOGLE_GENAI_API_VERSION, SSL_CERT_FILE); the key from the constructor
or GEMINI_API_KEY / GOOGLE_API_KEY, and it is never logged. Works with google-genai 3.x
(Python >= 3.11) and 2.33 (Python 3.10): only the API both have is used.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import ssl
from collections.abc import AsyncIterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal

from google import genai
from google.genai import errors, types
from websockets.exceptions import ConnectionClosed, InvalidStatus

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
from by_your_command.agents.providers.failures import closing_on_failure, handshake_refusal
from by_your_command.agents.providers.gemini_live.errors import (
    MISSING_KEY_MESSAGE,
    handshake_error,
    session_closed,
    setup_error,
)
from by_your_command.agents.providers.gemini_live.events import EventTranslator
from by_your_command.agents.providers.gemini_live.resumption import ResumptionHandles
from by_your_command.agents.providers.session_guards import check_whole_samples, open_session
from by_your_command.net.quiet_websockets import quiet_websocket_logger

log = logging.getLogger(__name__)

_SESSION = "the Gemini Live session"  # as errors name it
INPUT_RATE = 16_000  # Gemini Live's native input rate
INPUT_MIME = f"audio/pcm;rate={INPUT_RATE}"
DEFAULT_API_VERSION = "v1beta"  # the Live API's documented version (google-genai 3.x defaults to v1)
MAX_IMAGE_BYTES = 7 * 1024 * 1024
_QUIET_WEBSOCKET_LOG = quiet_websocket_logger(__name__)
_MEDIA_RESOLUTION = {
    "low": types.MediaResolution.MEDIA_RESOLUTION_LOW,
    "medium": types.MediaResolution.MEDIA_RESOLUTION_MEDIUM,
    "high": types.MediaResolution.MEDIA_RESOLUTION_HIGH,
}


@dataclass(frozen=True)
class GeminiLiveConfig:
    model: str = "gemini-3.8-live"
    voice: str = "Puck"  # a prebuilt voice name
    language_code: str = ""  # speech language, e.g. "en-US"; "" = the model's choice
    base_url: str = ""  # "" = GOOGLE_GEMINI_BASE_URL or Google's endpoint (always wss://)
    api_version: str = ""  # "" = GOOGLE_GENAI_API_VERSION or v1beta
    ca_file: str = ""  # a PEM CA to trust (a local emulator); "" = SSL_CERT_FILE or certifi
    extra_headers: tuple[tuple[str, str], ...] = ()
    # A text-only agent (SessionSetup.audio_out False): "transcription" asks for audio and uses its
    # transcription as the text (gemini-3.8-live speaks only); "text" asks for TEXT replies.
    text_replies: Literal["transcription", "text"] = "transcription"
    media_resolution: Literal["", "low", "medium", "high"] = "low"  # tokens per camera frame
    context_window_compression: bool = True  # sliding window: sessions beyond 15 min (2 with video)
    resumption: bool = True
    # Rotate before the server's hard close at ~58 min (1011 "Deadline expired", anchors §4).
    max_session_s: float = 50 * 60.0
    # websockets' 20 s ping timeout is shorter than Gemini's slowest pongs: a self-inflicted 1011.
    ping_interval_s: float | None = 20.0
    ping_timeout_s: float | None = 60.0  # None disables the check
    max_message_bytes: int = 8 * 1024 * 1024  # one server message (bounded memory)
    temperature: float | None = None
    max_output_tokens: int | None = None
    event_queue_size: int = 1024  # events the runtime has not read yet; the socket waits beyond it

    def __post_init__(self) -> None:
        if not self.model or not self.voice:
            raise ValueError("model and voice must not be empty")
        if self.text_replies not in ("transcription", "text"):
            raise ValueError("text_replies must be 'transcription' or 'text'")
        if self.media_resolution not in ("", *_MEDIA_RESOLUTION):
            raise ValueError("media_resolution must be '', low, medium or high")
        if not self.max_session_s > 0 or self.event_queue_size < 1 or self.max_message_bytes < 1024:
            raise ValueError("max_session_s must be > 0, event_queue_size >= 1, max_message_bytes >= 1024")
        for value in (self.ping_interval_s, self.ping_timeout_s):
            if value is not None and not value > 0:
                raise ValueError("ping_interval_s / ping_timeout_s must be > 0 or None")


class GeminiLiveProvider:
    """One Gemini Live connection (see agents/provider.py for the contract)."""

    name = "gemini_live"
    input_sample_rate = INPUT_RATE

    def __init__(
        self,
        config: GeminiLiveConfig | None = None,
        api_key: str | None = None,
        resumption: ResumptionHandles | None = None,
    ) -> None:
        self.config = config or GeminiLiveConfig()
        self.max_session_s = self.config.max_session_s
        self._api_key = api_key
        self._handles = resumption or ResumptionHandles()
        self._stack = contextlib.AsyncExitStack()
        self._session: Any = None  # genai.live.AsyncSession (typed Any: 2.33 and 3.x differ)
        self._events = EventStream(self.config.event_queue_size)
        self._translator = EventTranslator(audio_out=True, text_from_transcription=False)
        self._long_running: frozenset[str] = frozenset()  # NON_BLOCKING tools of this session
        self._reader: asyncio.Task[None] | None = None
        self._closed = False
        self._in_activity = False  # between our activityStart and activityEnd
        self._turn_audio_bytes = 0
        self.resumed = False  # this connection continues an earlier one (the server kept history)
        self._conversation_id = ""  # the runtime's conversation this session belongs to

    # ---- session ----------------------------------------------------------------------------
    async def connect(self, setup: SessionSetup) -> None:
        if self._session is not None or self._closed:
            raise ProviderClosed("a provider is one session: build a new one to reconnect")
        text_from_transcription = not setup.audio_out and self.config.text_replies == "transcription"
        self._translator = EventTranslator(setup.audio_out, text_from_transcription)
        self._long_running = frozenset(tool.name for tool in setup.tools if tool.long_running)
        client = self._client()
        # Resume only the conversation this session continues (a reset starts a new one, and the
        # store drops the old one's handle); an empty history has nothing to continue.
        self._conversation_id = setup.conversation_id
        handle = self._handles.usable(setup.conversation_id) if self.config.resumption else None
        handle = handle if setup.history else None
        try:
            await self._open(client, setup, handle)
        except ProviderFailure as failure:
            if failure.error.code != "resume_refused":
                raise
            log.info(
                "Gemini refused the resumption (%s): starting fresh with text context", failure.error.message
            )
            self._handles.forget()
            await self._open(client, setup, None)
        self._reader = asyncio.ensure_future(self._read(self._session))

    def _client(self) -> genai.Client:
        config = self.config
        client_args: dict[str, Any] = {
            "ping_interval": config.ping_interval_s,
            "ping_timeout": config.ping_timeout_s,
            "max_size": config.max_message_bytes,
            "logger": _QUIET_WEBSOCKET_LOG,
        }
        if config.ca_file:
            try:
                client_args["ssl"] = ssl.create_default_context(cafile=config.ca_file)
            except (OSError, ssl.SSLError) as error:
                raise ProviderFailure(
                    ProviderError(
                        "bad_ca_file", f"cannot read ca_file {config.ca_file!r}: {error}", fatal=True
                    )
                ) from None
        options = types.HttpOptions(
            base_url=config.base_url or None,
            api_version=config.api_version
            or os.environ.get("GOOGLE_GENAI_API_VERSION")
            or DEFAULT_API_VERSION,
            headers=dict(config.extra_headers) or None,
            async_client_args=client_args,
        )
        try:
            return genai.Client(api_key=self._api_key, http_options=options)
        except ValueError:  # no key given and none in the environment
            raise ProviderFailure(ProviderError("missing_api_key", MISSING_KEY_MESSAGE, fatal=True)) from None

    async def _open(self, client: genai.Client, setup: SessionSetup, handle: str | None) -> None:
        manager = client.aio.live.connect(model=self.config.model, config=self._live_config(setup, handle))
        try:
            self._session = await self._stack.enter_async_context(manager)
        except errors.APIError as refused:
            reason = str(refused.message or refused.details or "")
            error = setup_error(refused.code, reason, self.config.model, resuming=handle is not None)
            if error is not None:
                raise ProviderFailure(error) from None
            raise ProviderClosed(
                f"Gemini closed the connection during setup ({refused.code} {reason})"
            ) from None
        except InvalidStatus as refused:
            raise handshake_refusal(handshake_error(refused.response.status_code)) from None
        except ssl.SSLCertVerificationError as error:
            raise ProviderFailure(
                ProviderError(
                    "tls_untrusted",
                    f"the Gemini endpoint's certificate is not trusted ({error.verify_message}): set ca_file",
                    fatal=True,
                )
            ) from None
        self.resumed = handle is not None
        if not self.resumed and setup.history:
            async with closing_on_failure(_SESSION):
                await self._session.send_client_content(turns=_history(setup.history), turn_complete=False)

    def _live_config(self, setup: SessionSetup, handle: str | None) -> types.LiveConnectConfig:
        config = self.config
        text_modality = not setup.audio_out and config.text_replies == "text"
        speech = None
        if not text_modality:
            speech = types.SpeechConfig(
                voice_config=types.VoiceConfig(
                    prebuilt_voice_config=types.PrebuiltVoiceConfig(voice_name=config.voice)
                ),
                language_code=config.language_code or None,
            )
        return types.LiveConnectConfig(
            response_modalities=[types.Modality.TEXT if text_modality else types.Modality.AUDIO],
            speech_config=speech,
            system_instruction=setup.instructions or None,
            tools=_tools(setup.tools) or None,
            realtime_input_config=types.RealtimeInputConfig(
                automatic_activity_detection=types.AutomaticActivityDetection(disabled=True),
                activity_handling=types.ActivityHandling.START_OF_ACTIVITY_INTERRUPTS,
            ),
            input_audio_transcription=types.AudioTranscriptionConfig(),
            output_audio_transcription=None if text_modality else types.AudioTranscriptionConfig(),
            session_resumption=types.SessionResumptionConfig(handle=handle) if config.resumption else None,
            context_window_compression=types.ContextWindowCompressionConfig(
                sliding_window=types.SlidingWindow()
            )
            if config.context_window_compression
            else None,
            media_resolution=_MEDIA_RESOLUTION.get(config.media_resolution),
            temperature=config.temperature,
            max_output_tokens=config.max_output_tokens,
        )

    async def close(self) -> None:
        self._closed = True
        if self._reader is not None:
            self._reader.cancel()  # it may wait for room in a full queue nobody reads any more
            await asyncio.gather(self._reader, return_exceptions=True)
        else:
            self._events.end()
        self._session = None
        with contextlib.suppress(Exception):
            await self._stack.aclose()  # closes the socket (before any resume: sip-to-ai#14)

    # ---- input ------------------------------------------------------------------------------
    def _live(self) -> Any:
        return open_session(self._closed, self._session, _SESSION)

    async def _start_activity(self) -> None:
        if not self._in_activity:
            async with closing_on_failure(_SESSION):
                await self._live().send_realtime_input(activity_start=types.ActivityStart())
            self._in_activity = True
            self._turn_audio_bytes = 0

    async def send_audio(self, pcm: bytes) -> None:
        check_whole_samples(pcm)
        if not pcm:
            return
        session = self._live()
        await self._start_activity()  # never audio outside an activity: our VAD owns the turns
        async with closing_on_failure(_SESSION):
            await session.send_realtime_input(audio=types.Blob(data=pcm, mime_type=INPUT_MIME))
        self._turn_audio_bytes += len(pcm)

    async def end_of_turn(self) -> None:
        session = self._live()
        if not self._in_activity or not self._turn_audio_bytes:
            # Nothing to answer: no reply will come, so the runtime must fail the turn now (it
            # would wait for the reply timeout, then replay the same empty turn on a new session).
            await self._events.put(
                ProviderError("empty_turn", "utterance without audio not sent", refuses_turn=True)
            )
            return
        async with closing_on_failure(_SESSION):
            await session.send_realtime_input(activity_end=types.ActivityEnd())
        self._in_activity = False

    async def send_text(self, text: str) -> None:
        session = self._live()
        turn = types.Content(role="user", parts=[types.Part(text=text)])
        async with closing_on_failure(_SESSION):
            await session.send_client_content(turns=turn, turn_complete=True)

    async def add_context(self, text: str) -> None:
        """A user turn without turnComplete: it joins the history and asks for nothing."""
        session = self._live()
        turn = types.Content(role="user", parts=[types.Part(text=text)])
        async with closing_on_failure(_SESSION):
            await session.send_client_content(turns=turn, turn_complete=False)

    async def send_image(self, jpeg: bytes) -> None:
        """One camera frame as realtime video, sent once (the runtime gives each frame once)."""
        if not jpeg.startswith(b"\xff\xd8") or len(jpeg) > MAX_IMAGE_BYTES:
            raise ValueError(f"not a JPEG of at most {MAX_IMAGE_BYTES} bytes ({len(jpeg)} bytes)")
        session = self._live()
        async with closing_on_failure(_SESSION):
            await session.send_realtime_input(video=types.Blob(data=jpeg, mime_type="image/jpeg"))

    async def send_tool_results(self, results: Sequence[ToolResult]) -> None:
        """One toolResponse with every call's result (the model answers them together)."""
        session = self._live()
        responses = []
        for result in results:
            if result.call_id in self._translator.cancelled_calls:
                log.info("tool call %s was cancelled by the server: result dropped", result.call_id)
                continue
            try:
                parsed = json.loads(result.output)
            except ValueError:
                parsed = None
            content = parsed if isinstance(parsed, dict) else {"output": result.output}
            name = self._translator.call_name(result.call_id) or ""
            response = types.FunctionResponse(id=result.call_id, name=name, response=content)
            if name in self._long_running:  # NON_BLOCKING: the model speaks of it once it is idle
                response.scheduling = types.FunctionResponseScheduling.WHEN_IDLE
            responses.append(response)
        if not responses:
            return
        async with closing_on_failure(_SESSION):
            await session.send_tool_response(function_responses=responses)

    async def send_tool_progress(self, call_id: str, text: str) -> None:
        """A partial response of a NON_BLOCKING call (will_continue): heard silently, the call
        stays open for its final response."""
        session = self._live()
        name = self._translator.call_name(call_id) or ""
        if call_id in self._translator.cancelled_calls or name not in self._long_running:
            return
        progress = types.FunctionResponse(
            id=call_id,
            name=name,
            response={"progress": text},
            will_continue=True,
            scheduling=types.FunctionResponseScheduling.SILENT,
        )
        async with closing_on_failure(_SESSION):
            await session.send_tool_response(function_responses=[progress])

    async def interrupt(self, response_id: str, item_id: str, played_ms: int) -> None:
        """activityStart: the server stops generating and keeps what it sent in its history (there
        is no truncate). `played_ms` cannot be applied; the user's next audio follows in the same
        activity."""
        self._live()
        cut = response_id or self._translator.active_response
        if cut:
            self._translator.mark_cut(cut)
        if self._in_activity:  # an unfinished turn cannot be cut by another activityStart
            return
        await self._start_activity()

    # ---- output -----------------------------------------------------------------------------
    def events(self) -> AsyncIterator[ProviderEvent]:
        return self._events.__aiter__()

    async def _read(self, session: Any) -> None:
        why = "connection_lost"  # what a reply cut by the end of the connection reports
        try:
            while True:  # receive() ends at every turnComplete: keep reading the socket
                try:
                    async for message in session.receive():
                        await self._on_message(message)
                except ValueError as error:  # an unreadable message: report, keep the session
                    await self._events.put(
                        ProviderError("invalid_server_message", f"unreadable message: {error}")
                    )
        except errors.APIError as closed:
            reason = str(closed.message or closed.details or "")
            report = session_closed(closed.code, reason)
            if report is not None:
                log.info("Gemini closed the session: %s %s", closed.code, reason)
                self._events.put_last(report)
                why = report.message
        except ConnectionClosed:
            self._events.put_last(ProviderError("server_closed", "the Gemini connection was lost"))
        finally:
            self._closed = True
            for event in self._translator.connection_lost(why):
                self._events.put_last(event)
            self._events.end()

    async def _on_message(self, message: types.LiveServerMessage) -> None:
        update = message.session_resumption_update
        if update is not None and update.resumable and update.new_handle:
            self._handles.keep(update.new_handle, self._conversation_id)
        for event in self._translator.translate(message):
            await self._events.put(event)


def _history(history: Sequence[HistoryTurn]) -> list[types.Content]:
    return [
        types.Content(role="user" if turn.role is Role.USER else "model", parts=[types.Part(text=turn.text)])
        for turn in history
    ]


def _tools(tools: Sequence[ToolSpec]) -> types.ToolListUnion:
    if not tools:
        return []
    declarations = [
        types.FunctionDeclaration(
            name=tool.name,
            description=tool.description,
            parameters_json_schema=_gemini_schema(tool.parameters),
            # A robot action runs on while the conversation goes on; anything else is answered
            # at once (the robot's verdict), and the model waits for it.
            behavior=types.Behavior.NON_BLOCKING if tool.long_running else types.Behavior.BLOCKING,
        )
        for tool in tools
    ]
    return [types.Tool(function_declarations=declarations)]


# The JSON Schema keywords Gemini's parametersJsonSchema documents; others (contentEncoding, which
# robot tools put on uint8[] fields) are left out rather than risk a refused setup.
_SCHEMA_KEYWORDS = frozenset(
    {
        "type", "description", "properties", "required", "additionalProperties", "items", "enum",
        "minimum", "maximum", "minItems", "maxItems", "minLength", "maxLength", "format", "title",
        "nullable", "anyOf", "propertyOrdering",
    }
)  # fmt: skip


def _gemini_schema(schema: object) -> object:
    if isinstance(schema, list):
        return [_gemini_schema(item) for item in schema]
    if not isinstance(schema, dict):
        return schema
    out: dict[str, object] = {}
    for key, value in schema.items():
        if key == "properties" and isinstance(value, dict):  # names of fields, not keywords
            out[key] = {name: _gemini_schema(sub) for name, sub in value.items()}
        elif key in _SCHEMA_KEYWORDS:
            out[key] = _gemini_schema(value) if isinstance(value, (dict, list)) else value
    return out
