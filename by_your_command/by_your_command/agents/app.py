"""The agent process: a validated config → bridge client + port + provider factory + runtime, run
until a signal or a fatal error.

Exit codes: 0 stopped by SIGINT/SIGTERM (the provider session closed, metrics logged), 1 a fatal
error (the provider refused the key or the model, the bridge refused the token; the runtime logs
it as one line), 2 a configuration error (raised before anything starts). A second signal exits
at once. No ROS here: the agent reaches the robot only through ros_ai_bridge.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

from by_your_command.agents.app_config import AppConfig
from by_your_command.agents.app_providers import BuiltProvider, build_provider
from by_your_command.agents.bridge_port import BridgePort
from by_your_command.agents.config import AgentConfig, AgentConfigError, instructions_for
from by_your_command.agents.interruptions import Transcriber
from by_your_command.agents.overlap_words import LocalTranscriber
from by_your_command.agents.runtime import AgentFatal, AgentRuntime
from by_your_command.bridge.client import BridgeClient, ClientOptions
from by_your_command.config_files.locate import ConfigFileNotFound
from by_your_command.config_files.located_yaml import ConfigError
from by_your_command.prompts.library import PromptFileError, load_prompt_library
from by_your_command.stop_signals import StopRequests, StopVerdict
from by_your_command.vad.spoken_wake import RecognizerUnavailableError

log = logging.getLogger(__name__)

EXIT_STOPPED = 0
EXIT_FATAL = 1
EXIT_CONFIG = 2


@dataclass(frozen=True)
class PreparedAgent:
    """Everything checked before anything starts: a problem here is a config error (exit 2)."""

    app: AppConfig
    instructions: str
    provider: BuiltProvider
    bridge_token: str

    @property
    def secrets(self) -> tuple[str, ...]:
        return tuple(s for s in (self.provider.secret, self.bridge_token) if s)


def prepare(app: AppConfig, environ: Mapping[str, str]) -> PreparedAgent:
    """Resolve the prompt, the provider and the secrets; raises AgentConfigError naming every problem."""
    problems: list[str] = []
    instructions = ""
    try:
        library = load_prompt_library(app.agent.prompts_file or None)
        instructions = instructions_for(app.agent, library)
    except (ConfigFileNotFound, ConfigError, PromptFileError) as error:
        problems.append(f"prompts_file: {error}".replace("\n", " "))
    except AgentConfigError as error:
        problems.extend(error.problems)
    provider = None
    try:
        provider = build_provider(app.provider, environ)
    except AgentConfigError as error:
        problems.extend(error.problems)
    if problems:
        raise AgentConfigError(problems, app.source)
    assert provider is not None
    return PreparedAgent(app, instructions, provider, environ.get(app.bridge.token_env, "").strip())


def _barge_in_transcriber(config: AgentConfig) -> Transcriber | None:
    """The local recogniser that tells words from backchannels over the robot's voice, when a
    barge-in can happen and needs words; without pocketsphinx, the speech's length alone decides."""
    if not config.barge_in or config.min_barge_in_words <= 0:
        return None
    try:
        local = LocalTranscriber(config.backchannels)
    except RecognizerUnavailableError as error:
        log.warning("agent %s: barge-in judged on speech length only: %s", config.agent_id, error)
        return None

    one_at_a_time = asyncio.Lock()  # one decoder: an earlier barge-in's decode may still run

    async def transcribe(pcm: bytes, sample_rate: int) -> str:
        async with one_at_a_time:
            return await asyncio.to_thread(local, pcm, sample_rate)  # tens of ms: off the scheduler

    return transcribe


async def run_agent(prepared: PreparedAgent) -> int:
    """Run until SIGINT/SIGTERM (EXIT_STOPPED) or a fatal error (EXIT_FATAL)."""
    config = prepared.app.agent
    client = BridgeClient(prepared.app.bridge.url, ClientOptions(token=prepared.bridge_token))
    port = BridgePort(client, config)
    await port.setup()  # recorded by the client, sent at every (re)connect
    runtime = AgentRuntime(
        config,
        prepared.instructions,
        port,
        prepared.provider.factory,
        transcriber=_barge_in_transcriber(config),
    )
    log.info(
        "agent %s: role %s, provider %s (%s), bridge %s (%s)",
        config.agent_id,
        config.role.value,
        prepared.app.provider.type,
        prepared.provider.settings.get("model", "-"),
        prepared.app.bridge.url,
        "with token" if prepared.bridge_token else "no token",
    )
    with _stop_on_signals(runtime.stop):  # before anything starts: an early signal stops cleanly too
        try:
            if prepared.provider.warm_up is not None:
                try:
                    await asyncio.to_thread(prepared.provider.warm_up)
                except (ImportError, OSError, ValueError, RuntimeError) as error:
                    log.error("agent %s: the provider cannot start: %s", config.agent_id, error)
                    return EXIT_FATAL
            await client.start()
            await runtime.run()
            return EXIT_STOPPED
        except AgentFatal:
            return EXIT_FATAL  # the runtime logged the one line that says why
        except Exception:
            log.exception("agent %s: crashed", config.agent_id)
            return EXIT_FATAL
        finally:
            await client.close()


def run_agent_process(prepared: PreparedAgent) -> int:
    try:
        return asyncio.run(run_agent(prepared))
    except KeyboardInterrupt:  # Ctrl-C before the signal handlers were in place
        return EXIT_STOPPED


@contextlib.contextmanager
def _stop_on_signals(stop: Callable[[], None]) -> Iterator[None]:
    """The first SIGINT/SIGTERM stops the runtime cleanly; a second one exits at once, except the
    copy of one Ctrl-C that the terminal and a launcher both send (stop_signals.py)."""
    loop = asyncio.get_running_loop()
    requests = StopRequests()

    def on_signal(signum: int) -> None:
        verdict = requests.receive(signum)
        if verdict is StopVerdict.EXIT_NOW:
            log.warning("second signal: exiting without closing the session")
            os._exit(128 + signum)
        if verdict is StopVerdict.SAME_STOP:
            return  # the same Ctrl-C, sent by the terminal and by launch
        log.info("%s: stopping", signal.Signals(signum).name)
        stop()

    handled = (signal.SIGINT, signal.SIGTERM)
    for signum in handled:
        try:
            loop.add_signal_handler(signum, on_signal, signum)
        except NotImplementedError:  # Windows: no loop signal handlers; hop onto the loop instead
            signal.signal(signum, lambda number, _frame: loop.call_soon_threadsafe(on_signal, number))
    try:
        yield
    finally:
        for signum in handled:
            with contextlib.suppress(NotImplementedError):
                loop.remove_signal_handler(signum)
