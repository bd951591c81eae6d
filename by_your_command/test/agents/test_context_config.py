"""The context store's bounds and conversation ids; config validation; the prompt lookup."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from virtual_time import Deadlock, run_virtual

from by_your_command.agents.config import (
    AgentConfig,
    AgentConfigError,
    AgentRole,
    EchoMode,
    instructions_for,
    load_agent_config,
    parse_agent_config,
)
from by_your_command.agents.context import ContextStore
from by_your_command.agents.provider import Role
from by_your_command.prompts.library import load_prompt_library

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]


def test_context_keeps_the_newest_turns_within_tokens_and_age() -> None:
    store = ContextStore(max_tokens=10, max_age_s=100.0, conversation_timeout_s=600.0)
    store.new_conversation(0.0, 0.0)
    store.add(Role.USER, "a" * 16, 0.0)  # 4 tokens
    store.add(Role.ASSISTANT, "b" * 16, 1.0)
    store.add(Role.USER, "c" * 16, 2.0)  # 12 tokens in all: the oldest goes
    assert [h.text[0] for h in store.history(2.0)] == ["b", "c"]
    assert [h.text[0] for h in store.history(101.5)] == ["c"]  # b is older than 100 s
    store.add(Role.USER, "x" * 400, 102.0)  # larger than the whole budget: its end is kept
    [only] = store.history(102.0)
    assert only.text.endswith("x") and len(only.text) <= 40


def test_a_late_user_transcript_goes_before_the_reply_to_it() -> None:
    store = ContextStore(1000, 1000.0, 600.0)
    store.new_conversation(0.0, 0.0)
    store.add(Role.ASSISTANT, "earlier reply", 1.0)
    store.add(Role.ASSISTANT, "reply", 6.0)
    store.add_user_before_reply("question", 7.0, committed_at=5.0)
    assert [h.text for h in store.history(7.0)] == ["earlier reply", "question", "reply"]


def test_conversation_ids_change_on_reset_and_after_inactivity() -> None:
    store = ContextStore(1000, 1000.0, conversation_timeout_s=60.0)
    first = store.new_conversation(0.0, 1_800_000_000.0)
    store.add(Role.USER, "hello", 10.0)
    assert not store.expired(69.0) and store.expired(70.0)
    second = store.new_conversation(70.0, 1_800_000_070.0)
    assert second != first and store.history(70.0) == ()
    assert store.new_conversation(71.0, 0.0, "conv-from-outside") == "conv-from-outside"


def test_inactivity_starts_a_new_conversation_in_the_runtime() -> None:
    from fake_port import running_agent, speak
    from fake_provider import FakeFactory, spoken_reply

    async def scenario() -> None:
        factory = FakeFactory(spoken_reply("r1", 0.2), spoken_reply("r2", 0.2))
        async with running_agent(AgentConfig(conversation_timeout_s=60.0), factory) as agent:
            await speak(agent.port, 1, seconds=0.3)
            await asyncio.sleep(1.0)
            first = agent.runtime.context.conversation_id
            await asyncio.sleep(70.0)
            second = agent.runtime.context.conversation_id
            await speak(agent.port, 2, seconds=0.3)
            await asyncio.sleep(1.0)
            await agent.stop()
        assert first != second
        setup = factory.created[1].setup
        assert setup is not None and setup.history == ()  # the old conversation is not carried over

    run_virtual(scenario())


def test_config_defaults_and_a_valid_file(tmp_path: Path) -> None:
    path = tmp_path / "agent.yaml"
    path.write_text(
        "agent_id: conv\nrole: tools\necho_mode: aec\npause_timeout_s: 5\ntopics: {metrics: ''}\n"
    )
    config = load_agent_config(path)
    assert config.role is AgentRole.TOOLS and config.echo_mode is EchoMode.AEC
    assert config.pause_timeout_s == 5.0 and config.topics.metrics == "" and config.barge_in
    assert parse_agent_config(None) == AgentConfig()
    assert not AgentConfig(role=AgentRole.COMMAND, echo_mode=EchoMode.AEC).barge_in


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"pause_timout_s": 5}, "pause_timout_s: unknown key"),
        ({"pause_timeout_s": "5"}, "pause_timeout_s: must be a number"),
        ({"connect_attempts": 2.5}, "connect_attempts: must be int"),
        ({"role": "boss"}, "role: must be one of"),
        ({"topics": {"response_voce": "x"}}, "topics.response_voce: unknown key"),
        ({"reply_timeout_s": 0}, "reply_timeout_s: must be > 0"),
        ({"long_barge_in_ms": 200}, r"long_barge_in_ms: 0 \(off\) or >= min_barge_in_ms \(400\)"),
        ({"api_key": "sk-123"}, "api_key: keys come from the environment"),
        (
            {"provider": {"model": "m", "api_key": "sk-123"}},
            "provider.api_key: keys come from the environment",
        ),
        ([1, 2], "must be a mapping"),
    ],
)
def test_config_errors_name_the_key(data: object, message: str) -> None:
    with pytest.raises(AgentConfigError, match=message) as error:
        parse_agent_config(data)
    assert "sk-123" not in str(error.value)


def test_prompt_comes_from_the_library_and_a_missing_id_is_an_error() -> None:
    library = load_prompt_library()
    assert "robot_command" in instructions_for(AgentConfig(role=AgentRole.TOOLS), library)
    assert instructions_for(AgentConfig(prompt_id="command_extractor"), library) == library.system_prompt(
        "command_extractor"
    )
    with pytest.raises(AgentConfigError, match="prompt_id: no prompt 'nope'"):
        instructions_for(AgentConfig(prompt_id="nope"), library)


def test_virtual_time_reports_a_deadlock_instead_of_hanging() -> None:
    async def stuck() -> None:
        await asyncio.Event().wait()

    with pytest.raises(Deadlock):
        run_virtual(stuck(), deadline_s=None)
