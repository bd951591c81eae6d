"""The agent runtime: one scheduler task reacting to robot inputs, provider events and deadlines.

All state lives in this task and changes only here, one item at a time, so there are no races; the
I/O is at the edges (the RobotPort pump, the Session's writer/reader tasks). Every wait has a
deadline computed from the state (`_deadlines`), and every deadline handler changes the state.
docs/agents.md describes the behaviour; the comments here say why where it is not obvious.
"""

from __future__ import annotations

import asyncio
import logging
import secrets
from collections import deque
from collections.abc import Awaitable, Callable, Coroutine
from dataclasses import dataclass
from functools import partial
from typing import Any

from by_your_command.agents.clock import Clock, LoopClock
from by_your_command.agents.config import AgentConfig, ContextSource
from by_your_command.agents.context import ContextStore
from by_your_command.agents.events import (
    AssistantAudio,
    AssistantText,
    AssistantTranscript,
    Interrupted,
    ProviderError,
    ProviderEvent,
    ResponseDone,
    ResponseStatus,
    SessionEnding,
    ToolCall,
    ToolCallCancelled,
    Usage,
    UsageReport,
    UserTranscript,
)
from by_your_command.agents.frames import FrameChoice
from by_your_command.agents.inputs import (
    Attention,
    AttentionChanged,
    CallFeedback,
    CallReplied,
    CameraFrame,
    CommandStatus,
    ConversationReset,
    InputLost,
    PlaybackStatus,
    PromptText,
    RobotInput,
    SafetyStop,
    SharedTurn,
    ToolCatalog,
    UtteranceChunk,
    VoiceActivity,
)
from by_your_command.agents.interruptions import Heard, Interruptions, Transcriber
from by_your_command.agents.metrics import Counters
from by_your_command.agents.model_tool_calls import ModelToolCalls
from by_your_command.agents.outbox import Outbox
from by_your_command.agents.port import PortClosed, RobotPort, VoiceChunk
from by_your_command.agents.provider import ProviderFactory, Role, SessionSetup, ToolResult
from by_your_command.agents.reply_audio import ReplyAudio
from by_your_command.agents.reply_words import ReplyWords
from by_your_command.agents.reports import AgentReports
from by_your_command.agents.robot_calls import (
    RobotCalls,
    is_stop_request,
)
from by_your_command.agents.robot_runner import LATE_RESULT_NOTE, RobotToolRunner, SendFailed
from by_your_command.agents.rotation import ROTATION, SessionEnd
from by_your_command.agents.session import (
    AddContext,
    EndOfTurn,
    MuteInput,
    SendAudio,
    SendImage,
    SendText,
    SendToolResults,
    Session,
    SessionEvent,
    SessionFailed,
    SessionMessage,
    SessionOpened,
    SessionTimeouts,
)
from by_your_command.agents.tool_calls import PendingVerdicts
from by_your_command.agents.turn import Turn
from by_your_command.audio.pcm import StreamResampler
from by_your_command.net.backoff import backoff_s
from by_your_command.tools.catalog import RobotTool

log = logging.getLogger(__name__)

MIN_RATE, MAX_RATE = 8000, 192000  # what the player accepts; anything else is refused here
MAX_TEXT_CHARS = 4000  # a typed turn longer than this is cut (and counted)
MAX_FRAME_BYTES = 4 * 1024 * 1024
INPUT_BACKLOG = 256  # robot inputs queued before the pump stops reading (back-pressure to the bridge)
RECENT_UTTERANCES = 32  # closed utterance ids remembered, to tell late chunks from new utterances
# What the model reads in its history after the robot heard "stop" itself (the safety stop).
SAFETY_STOP_NOTE = (
    '"{phrase}" (the robot heard this itself and stopped at once: every motion command was '
    'stopped and the reply cut; it said "Stopping.")'
)
# A deadline this close is due now: sums of float times land a rounding error short of a
# deadline, and a wait of 1e-16 s never advances the clock (the loop would spin on it).
DEADLINE_SLACK_S = 1e-6


class AgentFatal(RuntimeError):
    """The agent cannot go on (bad key, unknown model, robot port refused): one clear message."""


class _Stop:
    pass


_STOP = _Stop()
_Item = RobotInput | SessionMessage | Heard | SendFailed | _Stop
# Items the scheduler made itself (or its sessions did): they hold no place in the input backlog.
_OWN_ITEMS = (SessionOpened, SessionEvent, SessionFailed, Heard, SendFailed)


@dataclass(frozen=True)
class _Deadline:
    when: float
    name: str
    handler: Callable[[], Awaitable[None]]


class AgentRuntime:
    def __init__(
        self,
        config: AgentConfig,
        instructions: str,
        port: RobotPort,
        provider_factory: ProviderFactory,
        clock: Clock | None = None,
        transcriber: Transcriber | None = None,
    ) -> None:
        self.config = config
        self._instructions = instructions
        self._port = port
        self._factory = provider_factory
        self._clock: Clock = clock or LoopClock()
        self.counters = Counters()
        self.context = ContextStore(
            config.max_context_tokens, config.max_context_age_s, config.conversation_timeout_s
        )
        self._queue: asyncio.Queue[_Item] = asyncio.Queue()
        self._input_room = asyncio.Semaphore(INPUT_BACKLOG)
        self._session: Session | None = None
        self._serial = 0
        self._not_before = 0.0  # no connect before this (rate limit)
        self._reconnect_at: float | None = None
        self._attempts = 0  # failed sessions since the last reply started
        self._attention = Attention.AWAKE
        self._turns = 0
        self._turn_in: Turn | None = None  # the utterance being received
        self._turn_out: Turn | None = None  # the committed turn whose reply is due or streaming
        self._waiting: deque[Turn] = deque()  # ended turns committed after the current reply
        self._closed_utterances: deque[int] = deque(maxlen=RECENT_UTTERANCES)
        self._reply: ReplyAudio | None = None  # the latest spoken reply (may still be playing)
        # Stream (and request) ids name this run too: a restarted agent's first reply must not
        # continue (or be dropped as) the stream its dead predecessor left in the player under the same id.
        self._run = secrets.token_hex(3)
        verdicts = PendingVerdicts()  # robot_command calls, and robot tools that are commands
        self.robot_calls = RobotCalls()
        self._tool_calls = ModelToolCalls(
            config,
            self.counters,
            verdicts,
            self.robot_calls,
            port,
            run=self._run,
            publish=self._publish,
            now=self._clock.now,
            turn=lambda: self._turn_out,
            session=lambda: self._session,
            start_robot=self._start_robot_call,
            stop_robot=lambda reason: self._robot.cancel_all(reason),
            result_turn=self._queue_result_turn,
            answered=self._tool_answered,
        )
        self._robot = RobotToolRunner(
            config.agent_id,
            self.robot_calls,
            verdicts,
            config.tool_verdict_timeout_s,
            port,
            self._clock,
            new_request_id=self._tool_calls.new_request_id,
            publish=self._publish,
            post=self._queue.put_nowait,
            deliver=self._tool_calls.deliver,
            tell_late=lambda note: self._queue_result_turn(-1, (), note),
            session=lambda: self._session,
        )
        self._provider_backlog = 0  # session messages in the queue, not handled yet
        self._frames = FrameChoice(config.max_frame_age_s)
        self._words = ReplyWords(
            config,
            self.context,
            self.counters,
            self._frames,
            port,
            publish=self._publish,
            now=self._clock.now,
            was_cut=lambda response_id: self._interruptions.was_cut(response_id),
            old_conversation=self._session_is_old_conversation,
        )
        self._utterance_ended_at = float("-inf")  # frames kept from before this are stale
        self._outbox = Outbox(config.agent_id, config.publish_timeout_s, self._count_publish_failure)
        self._interruptions = Interruptions(
            config,
            self.counters,
            port,
            transcriber,
            publish=self._publish,
            wall=self._clock.wall,
            discard_stream=self._outbox.discard_stream,
            session=lambda: self._session,
        )
        self._reports = AgentReports(
            config.agent_id,
            port,
            publish=self._publish,
            now=self._clock.now,
            conversation_id=lambda: self.context.conversation_id,
        )
        self._streams = 0
        self._last_activity = 0.0  # last exchange with the provider or the player (pause timer)
        self._awaited_at = 0.0  # last sign of life of the reply due (reply deadline)
        self._committed_at = 0.0  # when the latest turn was committed (orders late user transcripts)
        self._port_error = ""
        self._end = SessionEnd(config.pause_timeout_s, config.max_session_s, config.rotation_margin_s)
        self._session_conversation = 0  # the conversation (context.serial) the session serves
        self._spins = 0
        self._tasks: set[asyncio.Task[None]] = set()  # our own background work (transcriptions)
        # A full-duplex provider (GPT-Live) hears the user over its voice and yields by itself: no
        # barge-in judge, utterances end at once, and its own yield cuts the player (docs/gpt_live.md).
        self._duplex = False

    # --- public ------------------------------------------------------------------------------

    async def run(self) -> None:
        """Until the port's inputs end or stop() is called; raises AgentFatal with one message."""
        now = self._clock.now()
        self._last_activity = now
        self.context.new_conversation(now, self._clock.wall())
        self._outbox.start()
        pump = asyncio.create_task(self._pump_inputs(), name=f"{self.config.agent_id} inputs")
        log.info(
            "agent %s (%s) running, conversation %s",
            self.config.agent_id,
            self.config.role.value,
            self.context.conversation_id,
        )
        try:
            while True:
                item = await self._next_item()
                if isinstance(item, _Stop):
                    break
                if isinstance(item, (SessionOpened, SessionEvent, SessionFailed)):
                    self._provider_backlog -= 1
                try:
                    if item is not None:
                        await self._handle(item)
                    await self._run_due()
                    self._tool_calls.route(self._provider_backlog)
                except AgentFatal:
                    raise
                except Exception:
                    self.counters.internal_errors += 1
                    log.exception(
                        "agent %s: error handling %s (went on)", self.config.agent_id, type(item).__name__
                    )
                finally:
                    if item is not None and not isinstance(item, _OWN_ITEMS):
                        self._input_room.release()
            if self._port_error:
                raise AgentFatal(self._port_error)
        except AgentFatal as fatal:
            log.error("agent %s stopped: %s", self.config.agent_id, fatal)
            raise
        finally:
            pump.cancel()
            for task in self._tasks:
                task.cancel()
            await asyncio.gather(pump, *self._tasks, return_exceptions=True)
            if self._session is not None:
                await self._close_session("agent stopped")
            await self._outbox.close(self.config.publish_timeout_s)
            log.info("agent %s stopped; counters %s", self.config.agent_id, self.counters.snapshot())

    def stop(self) -> None:
        self._queue.put_nowait(_STOP)

    # --- the loop ----------------------------------------------------------------------------

    async def _pump_inputs(self) -> None:
        """Robot inputs into the scheduler's queue; a failing port is logged, counted and re-read."""
        failures = 0
        while True:
            try:
                async for item in self._port.inputs():
                    await self._input_room.acquire()
                    self._queue.put_nowait(item)
                    failures = 0
                break
            except asyncio.CancelledError:
                raise
            except PortClosed as closed:
                self._port_error = str(closed) or "the robot port closed"
                break
            except Exception:
                failures += 1
                self.counters.internal_errors += 1
                log.exception(
                    "agent %s: robot inputs failed (%d in a row); retrying", self.config.agent_id, failures
                )
                await self._clock.sleep(backoff_s(failures, 0.1, 5.0))
        self._queue.put_nowait(_STOP)

    async def _next_item(self) -> _Item | None:
        """The next queued item, or None when a deadline is due first. Items already queued are
        taken without waiting: `wait_for(get(), 0)` cancels the get before it runs, so a deadline
        that stayed due would otherwise starve the queue (stop() included) for good."""
        if not self._queue.empty():
            return self._queue.get_nowait()
        deadline = min((d.when for d in self._deadlines()), default=None)
        timeout = None if deadline is None else max(0.0, deadline - self._clock.now())
        if timeout is not None and timeout < DEADLINE_SLACK_S:
            timeout = 0.0
        if timeout == 0.0:
            if self._spins <= 2:
                return None
            timeout = 0.01  # a handler that did not clear its deadline must not spin the loop
        try:
            return await asyncio.wait_for(self._queue.get(), timeout)
        except asyncio.TimeoutError:
            return None

    async def _run_due(self) -> None:
        now = self._clock.now()
        now += DEADLINE_SLACK_S  # a deadline a rounding error away is due (else the loop spins)
        due = [d for d in self._deadlines() if d.when <= now]
        for deadline in due:
            await deadline.handler()
        still = [d.name for d in self._deadlines() if d.when <= now]
        if due and still:
            self._spins += 1
            if self._spins == 3:
                self.counters.internal_errors += 1
                log.error("agent %s: deadlines %s did not clear", self.config.agent_id, still)
        else:
            self._spins = 0

    def _deadlines(self) -> list[_Deadline]:
        c = self.config
        found: list[_Deadline] = []
        turn_in = self._turn_in
        if turn_in is not None:
            found.append(
                _Deadline(turn_in.last_chunk_at + c.utterance_idle_s, "utterance", self._utterance_idle)
            )
        out = self._turn_out
        if out is not None and not out.tool_calls_open:
            found.append(_Deadline(self._awaited_at + c.reply_timeout_s, "reply", self._reply_timed_out))
        barge_deadline = self._interruptions.deadline()
        if barge_deadline is not None:
            found.append(_Deadline(barge_deadline, "barge-in", self._judge_barge))
        tool_deadline = self._tool_calls.next_deadline()
        if tool_deadline is not None:
            found.append(_Deadline(tool_deadline, "tool verdict", self._tool_verdicts_late))
        calls_deadline = self.robot_calls.next_deadline()
        if calls_deadline is not None:
            found.append(_Deadline(calls_deadline, "robot calls", self._robot_calls_due))
        if self._reconnect_at is not None:
            found.append(_Deadline(self._reconnect_at, "reconnect", self._reconnect))
        reply = self._reply
        now = self._clock.now()
        playing_until = None if reply is None else reply.playing_until()
        if playing_until is not None and playing_until > now:
            found.append(_Deadline(playing_until, "playback", _nothing))
        if self._idle(now):
            if self._session is not None:
                found.append(
                    _Deadline(
                        self._end.close_at(self._session, self._last_activity),
                        "session",
                        self._close_idle_session,
                    )
                )
            expires = self.context.expires_at()
            if expires is not None:
                found.append(_Deadline(expires, "conversation", self._conversation_expired))
        return found

    def _idle(self, now: float) -> bool:
        """Nothing pending, and nothing audible of ours."""
        return self._nothing_pending() and not (self._reply is not None and self._reply.is_playing(now))

    def _nothing_pending(self) -> bool:
        """No turn, no tool call, no barge-in, no retry (a reply may still be playing)."""
        return (
            self._turn_in is None
            and self._turn_out is None
            and not self._waiting
            and not self._interruptions.pending
            and self._tool_calls.waiting() == 0
            # a running action keeps its session: only that session can take the call's result
            and not (self.robot_calls and self.config.keep_session_while_acting)
            and self._reconnect_at is None
        )

    # --- dispatch ----------------------------------------------------------------------------

    async def _handle(self, item: RobotInput | SessionMessage | Heard | SendFailed) -> None:
        if isinstance(item, (SessionOpened, SessionEvent, SessionFailed)):
            await self._on_session_message(item)
        elif isinstance(item, (CallReplied, CallFeedback, ToolCatalog, SendFailed)):
            await self._on_robot_tool_input(item)
        elif isinstance(item, Heard):
            await self._on_heard(item)
        elif isinstance(item, SafetyStop):
            await self._on_safety_stop(item)
        elif isinstance(item, UtteranceChunk):
            await self._on_chunk(item)
        elif isinstance(item, VoiceActivity):
            if item.active:
                await self._speech_onset()
        elif isinstance(item, PlaybackStatus):
            self._on_playback(item)
        elif isinstance(item, PromptText):
            await self._on_prompt_text(item)
        elif isinstance(item, AttentionChanged):
            if item.state is not self._attention:
                log.info("agent %s: attention %s", self.config.agent_id, item.state.value)
                was_awake = self._attention is Attention.AWAKE
                if (
                    self._duplex
                    and self._session is not None
                    and was_awake != (item.state is Attention.AWAKE)
                ):
                    self._session.send(MuteInput(was_awake))  # asleep or muted: so is the model's input
            self._attention = item.state
        elif isinstance(item, CameraFrame):
            self._on_frame(item)
        elif isinstance(item, CommandStatus):
            self._tool_calls.on_verdict(item)
        elif isinstance(item, InputLost):
            self.counters.inputs_lost += item.count if item.count is not None else 1
            log.warning(
                "agent %s: lost %s message(s) of %s: %s",
                self.config.agent_id,
                "unknown" if item.count is None else item.count,
                item.topic,
                item.reason,
            )
        elif isinstance(item, ConversationReset):
            await self._new_conversation("external reset", item.conversation_id)
        elif isinstance(item, SharedTurn):
            if self.config.context_source is ContextSource.SHARED:
                self.context.add(item.role, item.text, self._clock.now())

    # --- user input --------------------------------------------------------------------------

    async def _on_chunk(self, chunk: UtteranceChunk) -> None:
        if not MIN_RATE <= chunk.sample_rate <= MAX_RATE or len(chunk.pcm) % 2:
            self.counters.inputs_invalid += 1
            log.warning(
                "agent %s: refused an utterance chunk (rate %d, %d bytes)",
                self.config.agent_id,
                chunk.sample_rate,
                len(chunk.pcm),
            )
            return
        turn = self._turn_in
        if turn is not None and turn.utterance_id == chunk.utterance_id:
            await self._continue_utterance(turn, chunk)
            return
        if chunk.utterance_id in self._closed_utterances:
            self.counters.stray_chunks += 1  # late chunk of a closed (or deliberately ignored) utterance
            return
        if turn is not None:  # a new utterance while the last one never got its end marker
            self.counters.end_markers_missing += 1
            log.warning(
                "agent %s: utterance %d had no end marker; closed", self.config.agent_id, turn.utterance_id
            )
            await self._end_utterance(turn)
        if self._attention is not Attention.AWAKE:
            self.counters.ignored_not_awake += 1
            self._closed_utterances.append(chunk.utterance_id)
            return
        await self._speech_onset()
        session = self._ensure_session()
        now = self._clock.now()
        self._turns += 1
        turn = Turn(
            self._turns, "voice", now, self._keep_limit(session.input_sample_rate), chunk.utterance_id
        )
        turn.resampler = StreamResampler(chunk.sample_rate, session.input_sample_rate)
        turn.frame_since = self._utterance_ended_at
        turn.last_chunk_at = now
        turn.deferred = bool(self._waiting) and not self._duplex  # duplex: the model hears it now
        self._interruptions.join(turn)  # the speech over a paused reply: held until judged
        self._turn_in = turn
        await self._continue_utterance(turn, chunk)

    async def _continue_utterance(self, turn: Turn, chunk: UtteranceChunk) -> None:
        if chunk.chunk_sequence < turn.next_sequence:
            self.counters.stray_chunks += 1  # duplicate or reordered
            return
        if chunk.chunk_sequence > turn.next_sequence:
            missing = chunk.chunk_sequence - turn.next_sequence
            self.counters.chunks_missing += missing
            log.warning(
                "agent %s: utterance %d is missing %d chunk(s)",
                self.config.agent_id,
                chunk.utterance_id,
                missing,
            )
        first = turn.next_sequence == 0
        turn.next_sequence = chunk.chunk_sequence + 1
        turn.last_chunk_at = self._clock.now()
        assert turn.resampler is not None
        if chunk.sample_rate != turn.resampler.from_rate:
            self.counters.inputs_invalid += 1
            return
        self._append_audio(
            turn, turn.resample(chunk.pcm, chunk.sample_rate, chunk.is_end, chunk.unvoiced_samples)
        )
        if first and self._session is not None:
            # After the question's first audio (Gemini opens the user's activity with it), so the
            # frame is part of the question. Only a frame from the question's time goes now: an
            # older periodic one waits, since the one forwarded at the onset is usually a few ms
            # behind this chunk (_on_frame sends it); it goes at the end only if none came.
            since = max(turn.frame_since, turn.started_at - self.config.frame_lead_s)
            self._show(self._session, self._frames.give_to(turn.number, self._clock.now(), since))
        if chunk.is_end:
            await self._end_utterance(turn)
        elif self._interruptions.judges(turn):
            await self._judge_barge()
            self._hear_barge_in()

    def _append_audio(self, turn: Turn, pcm: bytes) -> None:
        turn.add_audio(pcm)
        if not turn.held and not turn.deferred and self._session is not None and pcm:
            self._session.send(SendAudio(pcm))
            self._last_activity = self._clock.now()

    async def _end_utterance(self, turn: Turn) -> None:
        now = self._clock.now()
        if not turn.ended and turn.resampler is not None and turn.resampler.received:
            self._append_audio(turn, turn.resample(b"", turn.resampler.from_rate, True))
        turn.ended_at = now
        self._turn_in = None
        self._utterance_ended_at = now
        if turn.utterance_id is not None:
            self._closed_utterances.append(turn.utterance_id)
        if self._interruptions.judges(turn):
            await self._judge_barge()
            self._hear_barge_in()  # the whole utterance, when its transcript is still wanted
            if turn.held:  # judged false, or still being judged: not sent (yet)
                return
        if self._duplex and turn.kind == "voice":
            await self._duplex_utterance_done(turn)
            return
        self._utterance_complete(turn)

    async def _duplex_utterance_done(self, turn: Turn) -> None:
        """Full duplex: the end goes to the model now, whatever it is saying (it decides whether to
        answer, and may already be). The turn it answers last is the one awaited; an earlier one
        still unanswered is finished as such."""
        session = self._ensure_session()
        previous = self._turn_out
        if previous is not None:
            await self._finish_turn(previous, "completed" if previous.reply_started else "unanswered")
        self._turn_out = turn
        turn.committed = True
        session.send(EndOfTurn())
        self._last_activity = self._awaited_at = self._committed_at = self._clock.now()

    def _utterance_complete(self, turn: Turn) -> None:
        """An ended utterance that is the user's turn: its frame if none went yet, then its commit."""
        session = self._session
        if session is not None and self._frames.asked_turn != turn.number and not turn.deferred:
            # no frame came while the question was spoken: an older one (fresh enough) is better
            # than none for "what do you see?"
            self._show(session, self._frames.give_to(turn.number, self._clock.now(), turn.frame_since))
        self._queue_commit(turn)

    async def _utterance_idle(self) -> None:
        turn = self._turn_in
        if turn is not None:
            self.counters.end_markers_missing += 1
            log.warning(
                "agent %s: utterance %s got no chunk for %.1f s and no end marker: closing it",
                self.config.agent_id,
                turn.utterance_id,
                self.config.utterance_idle_s,
            )
            await self._end_utterance(turn)

    async def _on_prompt_text(self, item: PromptText) -> None:
        text = item.text.strip()
        if not text:
            return
        if len(text) > MAX_TEXT_CHARS:
            self.counters.inputs_invalid += 1
            text = text[:MAX_TEXT_CHARS]
        if is_stop_request(text):  # before any other check: a typed stop is heard asleep too
            self._robot.cancel_all(f"the user said {text[:40]!r}")
        if self._attention is not Attention.AWAKE:
            self.counters.ignored_not_awake += 1
            return
        await self._rotate_before_a_new_turn()
        session = self._ensure_session()
        now = self._clock.now()
        self._turns += 1
        turn = Turn(self._turns, "text", now, self._keep_limit(session.input_sample_rate), text=text)
        turn.ended_at = now
        if self.config.context_source is ContextSource.OWN:
            self.context.add(Role.USER, text, now)
            self._publish("prompt_transcript", partial(self._port.publish_transcript, text))
        self._queue_commit(turn)

    def _on_frame(self, frame: CameraFrame) -> None:
        if not frame.jpeg or len(frame.jpeg) > MAX_FRAME_BYTES:
            self.counters.inputs_invalid += 1
            return
        now = self._clock.now()
        self._frames.keep(frame, now)
        turn = self._turn_in
        if (
            turn is not None
            and not turn.held
            and self._session is not None
            and self._frames.asked_turn != turn.number
        ):
            # The user is still asking: the first frame taken since the question started goes with
            # it (one per turn: later ones wait for the next turn, so a long question bills one).
            self._show(self._session, self._frames.give_to(turn.number, now))

    @staticmethod
    def _show(session: Session, frame: CameraFrame | None) -> None:
        if frame is not None:
            session.send(SendImage(frame.jpeg))

    # --- turns -------------------------------------------------------------------------------

    def _queue_commit(self, turn: Turn) -> None:
        """Commit now, or after the reply in progress (one reply at a time, whatever the provider)."""
        if self._turn_out is None and self._reconnect_at is None:
            self._commit(turn)
        else:
            self._waiting.append(turn)

    def _commit(self, turn: Turn) -> None:
        session = self._ensure_session()
        self._turn_out = turn
        turn.committed = True
        if turn.deferred:
            turn.deferred = False
            if not turn.replayable:
                log.warning(
                    "agent %s: turn %d waited for its commit longer than connect_buffer_s held: only its "
                    "first %.0f s are sent",
                    self.config.agent_id,
                    turn.number,
                    self.config.connect_buffer_s,
                )
            if turn.audio:
                session.send(SendAudio(bytes(turn.audio)))
        if turn.kind == "text":
            self._show(session, self._frames.take(self._clock.now()))
            session.send(SendText(turn.text))
        elif turn.kind == "tool":  # results of robot actions that ended after their turn
            if turn.tool_session == session.serial:
                session.send(SendToolResults(turn.tool_results))
            else:  # the calls were another session's: the model hears of them as a note
                session.send(SendText(turn.text))
        else:
            session.send(EndOfTurn())
        self._last_activity = self._awaited_at = self._committed_at = self._clock.now()

    async def _finish_turn(self, turn: Turn, outcome: str, why: str = "") -> None:
        now = self._clock.now()
        self._reports.turn(turn, outcome, why, self._serial, self._session, self._reply)
        if self._turn_out is turn:
            self._turn_out = None
        self.counters.turns += 1
        if self._session is not None:
            self._session.turns += 1
        if self._turn_out is None and self._session_is_old_conversation():
            await self._close_session_now(self._end.recycling or "new conversation")
        if self._waiting and self._turn_out is None and self._reconnect_at is None:
            self._commit(self._waiting.popleft())
        if self._idle(now) and (self._end.asked or self._end.rotation_due(self._session, now)):
            await self._close_session(self._end.asked or ROTATION)

    async def _fail_turn(self, turn: Turn, why: str) -> None:
        self.counters.turns_failed += 1
        await self._finish_turn(turn, "failed", why)

    async def _reply_timed_out(self) -> None:
        turn = self._turn_out
        if turn is None:
            return
        if self._duplex and turn.kind == "voice" and not turn.reply_started:
            # The model chose not to answer (a backchannel, a pause): its choice, not a failure.
            log.info("agent %s: turn %d was not answered", self.config.agent_id, turn.number)
            await self._finish_turn(turn, "unanswered")
            return
        # A reply that started is failed; one that never started is replayed on a new session.
        await self._lose_session(
            f"no answer from the provider within {self.config.reply_timeout_s:g} s",
            connected=True,
            error=None,
        )

    # --- barge-in ----------------------------------------------------------------------------

    async def _speech_onset(self) -> None:
        if self._attention is not Attention.AWAKE:
            return
        if not self._duplex:  # a full-duplex model hears the user and yields by itself
            self._interruptions.speech_onset(self._reply, self._clock.now())
        await self._rotate_before_a_new_turn()
        self._ensure_session()  # the connect hides behind the utterance that follows

    async def _rotate_before_a_new_turn(self) -> None:
        """A rotation that is due happens before a new turn at the latest. With turns back to back
        the session is never idle (the next question comes as the last reply ends), and it would
        reach the provider's limit in the middle of one."""
        if self._end.rotation_due(self._session, self._clock.now()) and self._nothing_pending():
            await self._close_session(ROTATION)

    def _hear_barge_in(self) -> None:
        """Transcribe the held speech (off the loop) when its words can still decide the barge-in."""
        hearing = self._interruptions.hearing()
        if hearing is not None:
            self._background(self._hear(hearing), "barge-in transcription")

    async def _hear(self, hearing: Callable[[], Awaitable[Heard]]) -> None:
        self._queue.put_nowait(await hearing())

    async def _on_heard(self, heard: Heard) -> None:
        if not self._interruptions.heard(heard):
            return  # judged meanwhile
        turn = self._interruptions.utterance
        await self._judge_barge()
        self._hear_barge_in()
        if turn is not None and not self._interruptions.pending and turn.ended and not turn.held:
            self._utterance_complete(turn)  # confirmed after the utterance ended

    async def _judge_barge(self) -> None:
        reply = self._interruptions.judge(self._clock.now(), self._turn_in)
        answered = self._turn_out
        if (
            reply is not None
            and reply.generation_done
            and answered is not None
            and answered.number == reply.turn
        ):
            await self._finish_turn(answered, "interrupted" if reply.cut else "completed")

    async def _on_safety_stop(self, stop: SafetyStop) -> None:
        """The robot heard "stop" itself: the command is routed and the player cut already. Our
        reply ends here (nothing more of it is published), the model's memory keeps only what was
        heard, and the conversation says that the user stopped the robot."""
        self.counters.safety_stops += 1
        self._robot.cancel_all(f"the robot heard {stop.phrase[:40]!r}")
        self._drop_stop_utterance(stop.utterance_id)
        answered = self._turn_out
        was_the_request = (
            bool(stop.utterance_id) and answered is not None and answered.utterance_id == stop.utterance_id
        )
        now = self._clock.now()
        reply = self._reply
        heard = self._interruptions.safety_stop(reply, now)  # it settles a barge-in too
        cut = heard is not None
        log.warning(
            "agent %s: safety stop heard (%r)%s",
            self.config.agent_id,
            stop.phrase,
            f": {reply.stream_id} cut at {heard} ms" if heard is not None and reply is not None else "",
        )
        if self.config.context_source is ContextSource.OWN and not self._session_is_old_conversation():
            note = SAFETY_STOP_NOTE.format(phrase=stop.phrase)
            self.context.add(Role.USER, note, now)  # for the next sessions
            if self._session is not None and not was_the_request:
                self._session.send(AddContext(note))  # for this one, without asking for a reply
        if was_the_request and answered is not None:
            await self._stop_was_the_request(answered)
        elif cut and reply is not None and reply.generation_done and answered is not None:
            if answered.number == reply.turn:
                await self._finish_turn(answered, "interrupted")

    async def _stop_was_the_request(self, turn: Turn) -> None:
        """The utterance the model is answering (or about to) was the stop: the VAD's end marker
        usually reaches us before the spotter's verdict. Its reply is neither said nor acted on:
        the session that took it as a request closes now (a reply to it, or a tool call routing
        "stop" again, would come from there), and the next session has the stop as a note."""
        self._turn_out = None
        await self._close_session_now("the user's stop was its request")
        log.info("agent %s: turn %d was the stop: its reply is dropped", self.config.agent_id, turn.number)
        await self._finish_turn(turn, "stopped")

    def _drop_stop_utterance(self, utterance_id: int) -> None:
        """The utterance that carried the stop word is not a request to the model: the stop is
        handled (the model would route it again, and answer). Its chunks still to come are dropped;
        audio of it already streamed to the provider would join the next turn there, so that
        session closes at the next boundary (the next one has the stop as a note in its history)."""
        if not utterance_id:
            return
        turn = self._turn_in
        if turn is not None and turn.utterance_id == utterance_id:
            self._turn_in = None
            if not turn.held and not turn.deferred and turn.audio and self._session is not None:
                self._end.recycle("a stop's audio is in the provider's input", self._clock.now())
        else:
            waiting = [t for t in self._waiting if t.utterance_id == utterance_id]
            for queued in waiting:
                self._waiting.remove(queued)
        if utterance_id not in self._closed_utterances:
            self._closed_utterances.append(utterance_id)
        log.info(
            "agent %s: utterance %d was the stop: not sent as a request", self.config.agent_id, utterance_id
        )

    def _on_playback(self, status: PlaybackStatus) -> None:
        reply = self._reply
        if reply is not None and status.stream_id == reply.stream_id:
            reply.status = status
            reply.status_at = self._clock.now()
            if status.speaking or status.paused:
                self._last_activity = self._clock.now()

    # --- provider events ---------------------------------------------------------------------

    async def _on_session_message(self, message: SessionMessage) -> None:
        session = self._session
        if session is None or message.serial != session.serial:
            return  # from a session already closed
        if isinstance(message, SessionOpened):
            self.counters.sessions_opened += 1
            self._reports.session_opened(session)
        elif isinstance(message, SessionFailed):
            await self._lose_session(message.reason, message.connected, message.error)
        else:
            self._last_activity = self._awaited_at = self._clock.now()
            await self._on_provider_event(session, message.event)

    async def _on_provider_event(self, session: Session, event: ProviderEvent) -> None:
        turn = self._turn_out
        if (
            isinstance(event, (AssistantAudio, AssistantTranscript, AssistantText, ToolCall))
            and turn is not None
        ):
            if not turn.reply_started:
                turn.reply_started = True
                turn.audio = bytearray()  # the reply started: no replay needed any more
                self._attempts = 0
        if isinstance(event, AssistantAudio):
            await self._on_audio(turn, event)
        elif isinstance(event, UserTranscript):
            self._add_usage(session, turn, event.usage)
            if not event.text.strip():
                self.counters.empty_transcripts += 1
                log.info("agent %s: the provider heard no words", self.config.agent_id)
            elif self.config.context_source is ContextSource.OWN:
                if is_stop_request(event.text):
                    self._robot.cancel_all(f"the user said {event.text.strip()[:40]!r}")
                if not self._session_is_old_conversation():
                    self.context.add_user_before_reply(event.text, self._clock.now(), self._committed_at)
                self._publish("prompt_transcript", partial(self._port.publish_transcript, event.text.strip()))
        elif isinstance(event, AssistantTranscript):
            if event.final:
                self._words.transcript(event.text, event.response_id)
        elif isinstance(event, AssistantText):
            if event.final:
                self._words.text_reply(event.text, event.response_id)
        elif isinstance(event, ToolCall):
            self._tool_calls.on_call(session.serial, turn, event, self._duplex)
        elif isinstance(event, ToolCallCancelled):
            if self._tool_calls.on_cancelled(event) and turn is not None:
                await self._finish_turn(turn, "cancelled")
        elif isinstance(event, ResponseDone):
            await self._on_response_done(session, turn, event)
        elif isinstance(event, Interrupted):
            reply = self._reply
            if reply is not None and reply.response_id == event.response_id:
                reply.generation_done = True
                if self._duplex and not reply.cut:
                    self._interruptions.model_yielded(reply, self._clock.now())
                else:
                    await self._end_stream(reply)
        elif isinstance(event, UsageReport):
            self._add_usage(session, turn, event.usage)
        elif isinstance(event, SessionEnding):
            self._end.provider_ends(f"the provider is ending the session ({event.reason})", self._clock.now())
            log.info(
                "agent %s: %s; rotating at the next turn boundary",
                self.config.agent_id,
                self._end.provider_ending,
            )
        else:
            await self._on_provider_error(event)

    async def _on_audio(self, turn: Turn | None, event: AssistantAudio) -> None:
        if not self.config.speaks or self._interruptions.was_cut(event.response_id) or not event.pcm:
            return
        if not MIN_RATE <= event.sample_rate <= MAX_RATE or len(event.pcm) % 2:
            self.counters.inputs_invalid += 1
            return
        reply = self._reply
        if reply is None or reply.response_id != event.response_id:
            reply = ReplyAudio(
                event.response_id,
                event.item_id,
                event.sample_rate,
                self._new_stream_id(),
                self._serial,
                turn.number if turn is not None else 0,
            )
            self._reply = reply
        if reply.sample_rate != event.sample_rate:
            self.counters.inputs_invalid += 1
            return
        reply.received_bytes += len(event.pcm)
        await self._publish_voice(reply, event.pcm)  # while paused, the player holds it
        if turn is not None and turn.first_audio_at is None:
            turn.first_audio_at = self._clock.now()

    # --- robot tools (docs/tools.md) ---------------------------------------------------------

    async def _on_robot_tool_input(self, item: CallReplied | CallFeedback | ToolCatalog | SendFailed) -> None:
        if isinstance(item, ToolCatalog):
            if self._tool_calls.take_catalog(item) and self._session is not None:
                # a session is told its tools when it opens
                self._end.recycle("the robot's tools changed", self._clock.now())
        else:
            self._robot.on_reply(item)

    def _start_robot_call(self, serial: int, tool: RobotTool, call: ToolCall) -> None:
        self._robot.start(serial, tool, call, self._attention, self.context.last_user_text())

    async def _robot_calls_due(self) -> None:
        self._robot.due()

    async def _tool_verdicts_late(self) -> None:
        self._tool_calls.verdicts_late()

    def _tool_answered(self) -> None:
        self._last_activity = self._awaited_at = self._clock.now()  # the reply deadline restarts

    def _queue_result_turn(self, serial: int, results: tuple[ToolResult, ...], note: str = "") -> None:
        """A turn of its own for results whose turn is over: sent as they are to the session that
        made the calls, or as a note to any other."""
        now = self._clock.now()
        self._turns += 1
        if not note:
            note = LATE_RESULT_NOTE.format(
                tool="(several)", arguments="", result="; ".join(result.output for result in results)
            )
        turn = Turn(self._turns, "tool", now, 0, text=note, tool_results=results, tool_session=serial)
        turn.ended_at = now
        self._queue_commit(turn)

    async def _on_response_done(self, session: Session, turn: Turn | None, done: ResponseDone) -> None:
        self._add_usage(session, turn, done.usage)
        self._tool_calls.response_done(done.response_id)
        reply = self._reply
        if reply is not None and reply.response_id == done.response_id:
            reply.generation_done = True
            if not reply.cut:
                await self._end_stream(reply)
        if turn is None:
            return
        if done.status is ResponseStatus.FAILED:
            await self._fail_turn(turn, f"the provider failed the reply ({done.reason or 'no reason'})")
        elif self._robot.started_action(done.response_id):
            # It started a robot action: its results (all of them, together) come when the action
            # ends, in a turn of their own; the conversation goes on meanwhile.
            turn.tool_calls_open.difference_update(self._tool_calls.calls_of(done.response_id))
            if not turn.tool_calls_open:
                await self._finish_turn(turn, "acting")
        elif turn.tool_calls_open or done.response_id in turn.tool_responses:
            return  # the reply continues once the verdicts are in (a tool-calling response is never the last)
        elif self._interruptions.judging(reply):
            return  # finished when the barge-in is judged
        else:
            outcome = "interrupted" if self._interruptions.was_cut(done.response_id) else done.status.value
            await self._finish_turn(turn, outcome)

    async def _on_provider_error(self, error: ProviderError) -> None:
        self.counters.provider_errors += 1
        if error.fatal:
            raise AgentFatal(_fatal_message(error))
        if error.retry_after_s is not None:
            self._not_before = max(self._not_before, self._clock.now() + error.retry_after_s)
            log.warning(
                "agent %s: rate limited (%s); no new session for %.1f s",
                self.config.agent_id,
                error.message,
                error.retry_after_s,
            )
        else:
            log.warning("agent %s: provider error %s: %s", self.config.agent_id, error.code, error.message)
        if error.refuses_turn and self._turn_out is not None:
            await self._fail_turn(self._turn_out, f"the provider refused it: {error.message}")

    def _add_usage(self, session: Session, turn: Turn | None, usage: Usage) -> None:
        session.usage = session.usage + usage
        if turn is not None:
            turn.usage = turn.usage + usage

    # --- sessions ----------------------------------------------------------------------------

    def _ensure_session(self) -> Session:
        if self._session is not None:
            return self._session
        try:
            provider = self._factory()
        except Exception as error:
            raise AgentFatal(f"cannot create the provider: {error}") from error
        now = self._clock.now()
        self._serial += 1
        setup = SessionSetup(
            self._instructions,
            self.context.history(now),
            self._tool_calls.specs(),
            audio_out=self.config.speaks,
            conversation_id=self.context.conversation_id,
        )
        timeouts = SessionTimeouts(
            self.config.connect_timeout_s, self.config.op_timeout_s, self.config.close_timeout_s
        )
        session = Session(self._serial, provider, setup, timeouts, self._clock, self._from_session)
        self._duplex = bool(getattr(provider, "duplex", False))
        if self._duplex and self._attention is not Attention.AWAKE:
            session.send(MuteInput(True))  # opened asleep (a running action's result): input muted
        self._session_conversation = self.context.serial
        session.start(delay_s=max(0.0, self._not_before - now, (self._reconnect_at or now) - now))
        self._session = session
        self._last_activity = now
        self._frames.new_session()
        if self._reconnect_at is not None:  # a new utterance came before the retry: retry now, behind it
            self._reconnect_at = None
            self._replay(session)
        return session

    def _from_session(self, message: SessionMessage) -> None:
        self._provider_backlog += 1  # tool commands wait until these are handled (_route_commands)
        self._queue.put_nowait(message)

    async def _close_session(self, reason: str) -> None:
        session = self._session
        if session is None:
            return
        self._session = None
        self._end.closed()
        self._tool_calls.forget_results()  # results only its own responses could take
        self._reports.session_closed(session, reason, await session.close())

    async def _close_idle_session(self) -> None:
        now = self._clock.now()
        if self._session is None or not self._idle(now):
            return
        await self._close_session(self._end.reason(self._session, now))

    async def _lose_session(self, reason: str, connected: bool, error: ProviderError | None) -> None:
        """The session died (or was given up): fail what was answering, replay what was not."""
        if error is not None and error.fatal:
            raise AgentFatal(_fatal_message(error))
        if error is not None and error.retry_after_s is not None:
            self._not_before = max(self._not_before, self._clock.now() + error.retry_after_s)
        if connected and self._end.provider_ending:
            # Announced (goAway) and closed before our turn boundary came, e.g. while the last reply
            # still played here: the end it announced, not a failure. A cut reply still fails below.
            log.info(
                "agent %s: session %d ended by the provider: %s", self.config.agent_id, self._serial, reason
            )
            await self._close_session(self._end.provider_ending)
        else:
            if connected:
                self.counters.sessions_failed += 1
            else:
                self.counters.connect_failures += 1
            log.warning("agent %s: session %d lost: %s", self.config.agent_id, self._serial, reason)
            await self._close_session(f"failed: {reason}")
        turn = self._turn_out
        if turn is not None and (turn.reply_started or not turn.replayable):
            await self._fail_turn(turn, f"the provider session was lost ({reason})")
        self._tool_calls.drop_waiting()
        turn = self._turn_out
        if turn is not None:  # never answered: it waits for the new session with the others
            self._turn_out = None
            self._waiting.appendleft(turn)
        pending = [*self._waiting, *([self._turn_in] if self._turn_in is not None else [])]
        if not pending:
            return
        self._attempts += 1
        if self._attempts >= self.config.connect_attempts or any(not t.replayable for t in pending):
            for lost in pending:
                self.counters.utterances_undeliverable += 1
                why = f"{reason} ({self._attempts} attempt(s))"
                self._reports.turn(lost, "undelivered", why, self._serial, self._session, self._reply)
            if self._turn_in is not None and self._turn_in.utterance_id is not None:
                self._closed_utterances.append(self._turn_in.utterance_id)  # its later chunks are stray
            self._turn_out = self._turn_in = None
            self._waiting.clear()
            self._attempts = 0
            return
        delay = backoff_s(self._attempts, self.config.backoff_initial_s, self.config.backoff_max_s)
        self._reconnect_at = max(self._clock.now() + delay, self._not_before)
        log.info(
            "agent %s: retrying %d turn(s) in %.1f s",
            self.config.agent_id,
            len(pending),
            self._reconnect_at - self._clock.now(),
        )

    async def _reconnect(self) -> None:
        self._ensure_session()  # replays the pending turns

    def _replay(self, session: Session) -> None:
        """Every turn not yet answered, in order, into a new session: the first is committed at once;
        the others wait for the reply as they did before, each sending its audio at its own commit
        (one input buffer: audio sent now would be taken by the first commit)."""
        for waiting in self._waiting:
            waiting.deferred = True  # nothing of theirs is in the new session yet
        if self._waiting:
            self._commit(self._waiting.popleft())  # sends its audio, then commits
        speaking = self._turn_in
        if speaking is not None and not speaking.held:
            speaking.deferred = bool(self._waiting)
            if speaking.audio and not speaking.deferred:
                session.send(SendAudio(bytes(speaking.audio)))

    async def _new_conversation(self, why: str, conversation_id: str = "") -> None:
        now = self._clock.now()
        old = self.context.conversation_id
        new = self.context.new_conversation(now, self._clock.wall(), conversation_id)
        log.info("agent %s: conversation %s → %s (%s)", self.config.agent_id, old, new, why)
        if self._session is None:
            return
        if self._turn_out is None:
            await self._close_session_now(f"new conversation ({why})")
        else:  # a reply is being made: it ends first, then the session goes (_finish_turn)
            self._end.recycle(f"new conversation ({why})", self._clock.now(), replace=True)

    def _session_is_old_conversation(self) -> bool:
        return self._session is not None and self._session_conversation != self.context.serial

    async def _close_session_now(self, reason: str) -> None:
        """Close the session now, even while its last reply still plays (an old conversation's, or
        one that took a stop as a request), so its server-side history never answers what the user
        says from here on: that goes to a new session, from its kept audio."""
        for turn in self._waiting:
            turn.deferred = True
        if self._turn_in is not None and not self._turn_in.held:
            self._turn_in.deferred = True
        self._tool_calls.drop_waiting()  # its calls were the old session's
        await self._close_session(reason)

    async def _conversation_expired(self) -> None:
        if self.context.expired(self._clock.now()):
            await self._new_conversation("inactivity")

    # --- output ------------------------------------------------------------------------------

    def _new_stream_id(self) -> str:
        self._streams += 1
        return f"{self.config.agent_id}-{self._run}-{self._serial}-{self._streams}"

    async def _publish_voice(self, reply: ReplyAudio, pcm: bytes) -> None:
        if reply.stream_started_at is None:
            reply.stream_started_at = self._clock.now()
        chunk = VoiceChunk(reply.stream_id, pcm, reply.sample_rate, False, self._clock.wall())
        self._outbox.voice(reply.stream_id, len(pcm), partial(self._port.publish_voice, chunk))

    async def _end_stream(self, reply: ReplyAudio) -> None:
        if reply.ended_stream or reply.stream_started_at is None:
            return
        reply.ended_stream = True
        chunk = VoiceChunk(reply.stream_id, b"", reply.sample_rate, True, self._clock.wall())
        self._outbox.voice(reply.stream_id, 0, partial(self._port.publish_voice, chunk))

    def _background(self, work: Coroutine[Any, Any, None], name: str) -> None:
        """Run `work` beside the scheduler (it reports back through the queue; it catches its own
        errors). Kept referenced until done, cancelled at stop."""
        task = asyncio.create_task(work, name=f"{self.config.agent_id} {name}")
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _publish(self, what: str, send: Callable[[], Awaitable[None]]) -> None:
        """Queued for the outbox's worker: the scheduler never waits on the bridge."""
        self._outbox.control(what, send)

    def _count_publish_failure(self) -> None:
        self.counters.publish_failures += 1

    def _keep_limit(self, rate: int) -> int:
        return int(self.config.connect_buffer_s * rate) * 2


async def _nothing() -> None:
    """The playback estimate ran out: nothing to do but look at the deadlines again."""


def _fatal_message(error: ProviderError) -> str:
    return f"the provider refused to serve this agent: {error.code}: {error.message}"
