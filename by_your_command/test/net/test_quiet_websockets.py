"""The websockets logger every connection uses (net/quiet_websockets.py): the handshake headers,
where API keys and the bridge token travel, never reach a log, even with logging at DEBUG."""

from __future__ import annotations

import asyncio
import logging

import pytest
from websockets.asyncio.client import connect
from websockets.asyncio.server import ServerConnection, serve

from by_your_command.net.quiet_websockets import quiet_websocket_logger

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

SECRET = "sk-test-5d1e0b9a7c"  # a recognisable fake key


async def echo(connection: ServerConnection) -> None:
    async for message in connection:
        await connection.send(message)


async def handshake_with_the_secret(
    server_log: logging.Logger | None = None, client_log: logging.Logger | None = None
) -> None:
    """One connection whose request carries the secret in a header, one message each way."""
    async with serve(echo, "127.0.0.1", 0, logger=server_log) as server:
        port = server.sockets[0].getsockname()[1]
        headers = {"Authorization": f"Bearer {SECRET}"}
        async with connect(f"ws://127.0.0.1:{port}", additional_headers=headers, logger=client_log) as client:
            await client.send("ping")
            assert await client.recv() == "ping"


def logged_lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    """Each record as a handler writes it (name, level and the message with its arguments)."""
    full = logging.Formatter("%(name)s %(levelname)s %(message)s")
    return [full.format(record) for record in caplog.records]


def test_websockets_own_loggers_would_log_the_secret(caplog: pytest.LogCaptureFixture) -> None:
    """The leak the helper exists for: without it, the handshake headers are logged at DEBUG."""
    with caplog.at_level(logging.DEBUG):
        asyncio.run(handshake_with_the_secret())
    assert [line for line in logged_lines(caplog) if SECRET in line]


def test_quiet_loggers_never_log_the_secret(caplog: pytest.LogCaptureFixture) -> None:
    server_log = quiet_websocket_logger("quiet_test.server")
    client_log = quiet_websocket_logger("quiet_test.client")
    with caplog.at_level(logging.DEBUG):
        asyncio.run(handshake_with_the_secret(server_log, client_log))
    assert not [line for line in logged_lines(caplog) if SECRET in line]
    assert (server_log.name, client_log.name) == (
        "quiet_test.server.websocket",
        "quiet_test.client.websocket",
    )


def test_quiet_loggers_still_pass_warnings_on() -> None:
    logger = quiet_websocket_logger("quiet_test.warnings")
    assert not logger.isEnabledFor(logging.DEBUG)
    assert logger.isEnabledFor(logging.INFO) and logger.isEnabledFor(logging.WARNING)
