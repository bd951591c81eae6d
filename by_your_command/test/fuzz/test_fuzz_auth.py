"""Unauthorised access attempts on the bridge's WebSocket handshake, over real loopback sockets.

Complements test/bridge/test_bridge_server.py (missing or wrong token, `?token=`, foreign and
allowed origins, too many clients): here the token is offered in odd places and odd forms, origins
look almost like the bridge's own, headers are oversize or not ASCII, and random Authorization
values and URLs are tried. None may open a session; each gets an HTTP refusal (or a closed socket),
never a server error; and a well-behaved client is served afterwards.
"""

from __future__ import annotations

import asyncio
import base64
import logging
import os
import re
from collections.abc import Coroutine
from typing import Any

import pytest
from bridge_fakes import running_bridge
from fuzzing import TALLY, fuzz_settings
from hypothesis import given
from hypothesis import strategies as st
from websockets.asyncio.client import connect

from by_your_command.bridge.server import BridgeServer

pytestmark = [pytest.mark.unit, pytest.mark.timeout(300)]

TOKEN = "s3cret-Token_42"
STATUS_LINE = re.compile(rb"^HTTP/1\.1 (\d{3}) ")


def run(coroutine: Coroutine[Any, Any, None]) -> None:
    asyncio.run(asyncio.wait_for(coroutine, 120))


def handshake(port: int, headers: list[bytes], path: bytes = b"/") -> bytes:
    key = base64.b64encode(os.urandom(16))
    lines = [
        b"GET " + path + b" HTTP/1.1",
        f"Host: 127.0.0.1:{port}".encode(),
        b"Upgrade: websocket",
        b"Connection: Upgrade",
        b"Sec-WebSocket-Key: " + key,
        b"Sec-WebSocket-Version: 13",
        *headers,
    ]
    return b"\r\n".join(lines) + b"\r\n\r\n"


async def attempt(server: BridgeServer, headers: list[bytes], path: bytes = b"/") -> int | None:
    """The HTTP status the bridge answers a raw handshake with (None: it closed without one)."""
    reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
    try:
        writer.write(handshake(server.port, headers, path))
        await writer.drain()
        head = await asyncio.wait_for(reader.readline(), 30)  # a bound on the answer, not a timing test
    except ConnectionError:
        return None
    finally:
        writer.close()
    match = STATUS_LINE.match(head)
    return int(match.group(1)) if match else None


async def still_serves(server: BridgeServer) -> None:
    async with connect(
        f"ws://127.0.0.1:{server.port}/", additional_headers={"Authorization": f"Bearer {TOKEN}"}
    ) as ws:
        await ws.send('{"op":"unsubscribe","topic":"prompt_text","id":"ping"}')
        reply = await asyncio.wait_for(ws.recv(), 30)
        assert '"id":"ping"' in str(reply) and '"not_subscribed"' in str(reply)


TOKEN_IN_ODD_PLACES: list[tuple[str, list[bytes], bytes]] = [
    ("basic scheme", [b"Authorization: Basic " + base64.b64encode(f"user:{TOKEN}".encode())], b"/"),
    ("no scheme", [f"Authorization: {TOKEN}".encode()], b"/"),
    ("token scheme", [f"Authorization: Token {TOKEN}".encode()], b"/"),
    ("bearer without token", [b"Authorization: Bearer"], b"/"),
    ("upper-cased token", [f"Authorization: Bearer {TOKEN.upper()}".encode()], b"/"),
    ("prefix of the token", [f"Authorization: Bearer {TOKEN[:-1]}".encode()], b"/"),
    ("token plus a character", [f"Authorization: Bearer {TOKEN}x".encode()], b"/"),
    ("token and junk", [f"Authorization: Bearer {TOKEN} extra".encode()], b"/"),
    ("non-ASCII after the token", [f"Authorization: Bearer {TOKEN}".encode() + b"\xe9"], b"/"),
    ("zero-width space in it", [f"Authorization: Bearer {TOKEN[:3]}\u200b{TOKEN[3:]}".encode()], b"/"),
    ("in a cookie", [f"Cookie: token={TOKEN}".encode()], b"/"),
    ("as a subprotocol", [f"Sec-WebSocket-Protocol: {TOKEN}".encode()], b"/"),
    ("in another header", [f"X-Token: {TOKEN}".encode()], b"/"),
    ("in the path", [], f"/{TOKEN}".encode()),
    ("query key in capitals", [], f"/?TOKEN={TOKEN}".encode()),
    ("query key misspelt", [], f"/?tokens={TOKEN}".encode()),
    ("empty query token", [], b"/?token="),
    ("wrong query token first", [], f"/?token=nope&token={TOKEN}".encode()),
    ("percent-encoded junk", [], b"/?token=%ff%fe"),
    ("token in a fragment", [], f"/#token={TOKEN}".encode()),
]


@pytest.mark.parametrize(
    ("name", "headers", "path"), TOKEN_IN_ODD_PLACES, ids=[case[0] for case in TOKEN_IN_ODD_PLACES]
)
def test_the_token_anywhere_but_where_it_belongs_is_refused(
    name: str, headers: list[bytes], path: bytes
) -> None:
    async def scenario() -> None:
        async with running_bridge(token=TOKEN) as (server, _):
            status = await attempt(server, headers, path)
            assert status in (401, 400, None), (name, status)
            assert not server.core.sessions and server.admitted == 0
            await still_serves(server)

    run(scenario())


def test_origins_that_only_look_like_the_bridges_own_are_refused() -> None:
    async def scenario() -> None:
        async with running_bridge(token=TOKEN) as (server, _):
            port = server.port
            bearer = f"Authorization: Bearer {TOKEN}".encode()
            for origin in (
                f"http://127.0.0.1:{port}.evil.example",
                f"http://127.0.0.1:{port}@evil.example",
                f"http://evil.example#http://127.0.0.1:{port}",
                f"https://127.0.0.1:{port}",  # another scheme is another origin
                f"http://127.0.0.1:{port}/monitor",
                f"http://127.0.0.1:{port}0",
                f"http://127.0.0.2:{port}",
                f"http://localhost.:{port}",
                f"http://[::ffff:127.0.0.1]:{port}",
                f"ws://127.0.0.1:{port}",
                "file://",
                "",
            ):
                status = await attempt(server, [bearer, f"Origin: {origin}".encode()])
                assert status == 403, (origin, status)
            assert await attempt(server, [bearer, b"Origin: http://\xe9vil.example"]) == 403
            assert await attempt(server, [bearer, f"Origin: HTTP://LOCALHOST:{port}".encode()]) == 101
            assert server.refused_connections == 13
            await still_serves(server)

    run(scenario())


def test_oversize_or_malformed_handshakes_are_refused_and_the_bridge_goes_on() -> None:
    async def scenario() -> None:
        async with running_bridge(token=TOKEN) as (server, _):
            bearer = f"Authorization: Bearer {TOKEN}".encode()
            assert await attempt(server, [bearer, b"X-Big: " + b"a" * 20_000]) == 431
            assert await attempt(server, [bearer, *(f"X-{i}: a".encode() for i in range(300))]) == 431
            assert await attempt(server, [bearer], b"/?" + b"a" * 20_000) == 414
            assert await attempt(server, [bearer + b"\x01"]) is None  # a control character: dropped
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            writer.write(os.urandom(4096) + b"\r\n\r\n")  # not HTTP at all: answered and closed
            await writer.drain()
            await asyncio.wait_for(reader.read(), 30)
            writer.close()
            assert not server.core.sessions
            await still_serves(server)

    run(scenario())


@pytest.mark.parametrize("header", [b"Origin", b"Authorization"])
def test_a_repeated_origin_or_authorization_header_is_refused_not_a_server_error(header: bytes) -> None:
    async def scenario() -> None:
        async with running_bridge(token=TOKEN) as (server, _):
            value = b"Bearer " + TOKEN.encode() if header == b"Authorization" else b"http://evil.example"
            headers = [f"Authorization: Bearer {TOKEN}".encode()] if header == b"Origin" else []
            status = await attempt(server, [*headers, header + b": " + value, header + b": " + value + b"2"])
            assert status == 400, status

    run(scenario())


AUTHORIZATION_VALUES = st.one_of(
    st.binary(max_size=60).filter(lambda b: b"\r" not in b and b"\n" not in b),
    st.builds(
        lambda scheme, space, token: scheme + space + token,
        st.sampled_from([b"Bearer", b"bearer", b"BEARER", b"Basic", b"", b"Bearer\t"]),
        st.sampled_from([b" ", b"  ", b"\t", b""]),
        st.sampled_from([TOKEN.encode()[:i] for i in range(len(TOKEN))]).map(lambda t: t)
        | st.text(max_size=20)
        .map(lambda t: t.encode("utf-8"))
        .filter(lambda b: b"\r" not in b and b"\n" not in b)
        | st.just(TOKEN.encode()).map(lambda t: t + b"!"),
    ),
)
QUERIES = st.text(max_size=40).map(lambda t: b"/?" + t.encode("utf-8").replace(b" ", b"%20"))


@fuzz_settings(short=40, long=500)
@given(st.lists(st.tuples(AUTHORIZATION_VALUES, QUERIES), min_size=1, max_size=5))
def test_random_credentials_never_open_a_session(attempts: list[tuple[bytes, bytes]]) -> None:
    async def scenario() -> None:
        async with running_bridge(token=TOKEN) as (server, _):
            for authorization, query in attempts:
                if authorization.strip() and TOKEN.encode() == authorization.split(maxsplit=1)[-1].strip():
                    continue  # that one is the token
                if f"token={TOKEN}".encode() in query:
                    continue
                status = await attempt(
                    server, [b"Authorization: " + authorization], query.split(b"#")[0] or b"/"
                )
                assert status in (400, 401, None), (authorization, query, status)
            assert not server.core.sessions and server.admitted == 0
            await still_serves(server)

    with TALLY.input("bridge handshake (credentials)", count=len(attempts)):
        run(scenario())


def test_refusals_never_log_the_token(caplog: pytest.LogCaptureFixture) -> None:
    async def scenario() -> None:
        async with running_bridge(token=TOKEN) as (server, _):
            for headers, path in [
                ([f"Authorization: Bearer {TOKEN}x".encode()], b"/"),
                ([], f"/?token={TOKEN}0".encode()),
            ]:
                assert await attempt(server, headers, path) == 401

    with caplog.at_level(logging.DEBUG):
        run(scenario())
    assert "refused" in caplog.text and TOKEN not in caplog.text
