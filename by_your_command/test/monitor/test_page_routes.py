"""The monitor page over plain HTTP on the bridge's own port: token, origin and routing rules."""

from __future__ import annotations

import http.client
import json
import re

import pytest
import yaml
from live_bridge import CONFIG_DIR, LiveBridge, live_bridge
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

TOKEN = "page-token-7c1d"


def get(
    bridge: LiveBridge, path: str, headers: dict[str, str] | None = None, method: str = "GET"
) -> tuple[int, dict[str, str], bytes]:
    connection = http.client.HTTPConnection("127.0.0.1", bridge.port, timeout=10)
    try:
        connection.request(method, path, headers=headers or {})
        response = connection.getresponse()
        return response.status, {k.lower(): v for k, v in response.getheaders()}, response.read()
    finally:
        connection.close()


def test_the_page_is_served_on_loopback_without_a_token_with_strict_headers() -> None:
    with live_bridge() as bridge:
        for path in ("/", "/monitor", "/?token=anything"):
            status, headers, body = get(bridge, path)
            assert status == 200, path
            assert headers["content-type"] == "text/html; charset=utf-8"
            policy = headers["content-security-policy"]
            assert "default-src 'self'" in policy and "frame-ancestors 'none'" in policy
            assert "'unsafe-inline'" not in policy and "'unsafe-eval'" not in policy
            assert headers["x-content-type-options"] == "nosniff"
            assert headers["referrer-policy"] == "no-referrer"  # the URL may carry the token
        html = body.decode()
        # No inline code: every script is a file, no event-handler attributes, no style blocks.
        assert re.findall(r"<script\b[^>]*>", html) == [
            '<script src="records.js" defer>',
            '<script src="monitor.js" defer>',
        ]
        assert not re.search(r"\son[a-z]+\s*=", html) and "<style" not in html
        for script_path in ("/records.js", "/monitor.js"):
            status, headers, script = get(bridge, script_path)
            assert (status, headers["content-type"]) == (200, "text/javascript; charset=utf-8")
            assert b"innerHTML" not in script  # data reaches the page through textContent only
        status, headers, settings = get(bridge, "/monitor-config.json")
        assert (status, headers["content-type"]) == (200, "application/json")
        shipped = yaml.safe_load((CONFIG_DIR / "monitor.yaml").read_text())
        served = json.loads(settings)
        assert (
            served["prices"]["openai_realtime"]["output_audio"]
            == shipped["prices"]["openai_realtime"]["output_audio"]
        )
        assert served["page"] == shipped["page"]


def test_with_a_token_the_page_and_its_settings_need_it() -> None:
    with live_bridge(token=TOKEN) as bridge:
        for path in ("/", "/monitor", "/?token=wrong", "/monitor-config.json", "/?token="):
            status, _, body = get(bridge, path)
            assert status == 401, path
            assert TOKEN.encode() not in body
        assert get(bridge, f"/?token={TOKEN}")[0] == 200
        assert get(bridge, f"/monitor?token={TOKEN}")[0] == 200
        assert get(bridge, "/", {"Authorization": f"Bearer {TOKEN}"})[0] == 200
        assert get(bridge, f"/monitor-config.json?token={TOKEN}")[0] == 200
        # The page asks with a header: a failed request's URL (printed by the browser) holds no token.
        assert get(bridge, "/monitor-config.json", {"Authorization": f"Bearer {TOKEN}"})[0] == 200
        # The scripts and the style are the same public code for everyone, without robot data.
        for public in ("/monitor.js", "/records.js", "/monitor.css"):
            assert get(bridge, public)[0] == 200, public
        # Without the token an unknown path says nothing about what exists.
        assert get(bridge, "/secret")[0] == 401
        assert get(bridge, f"/secret?token={TOKEN}")[0] == 404
        assert bridge.server.refused_connections >= 6


def test_foreign_origins_are_refused_for_the_page_and_the_socket() -> None:
    with live_bridge() as bridge:
        for origin in ("http://evil.example", "http://127.0.0.1:1", "null"):
            assert get(bridge, "/", {"Origin": origin})[0] == 403, origin
            assert get(bridge, "/monitor.js", {"Origin": origin})[0] == 403, origin
        assert get(bridge, "/", {"Origin": f"http://localhost:{bridge.port}"})[0] == 200
        with pytest.raises(InvalidStatus) as refused:
            connect(f"ws://127.0.0.1:{bridge.port}/", origin="http://evil.example")  # type: ignore[arg-type]
        assert refused.value.response.status_code == 403


@pytest.mark.parametrize(
    "path",
    [
        "/../config/bridge.yaml",
        "/static/index.html",
        "/monitor/static/monitor.js",
        "/%2e%2e/setup.py",
        "/monitor.js/../monitor-config.json",
        "//monitor.js",
        "/MONITOR.JS",
        "/monitor.js%00",
        "/index.html",
        "/monitor/",
        "/monitor.yaml",
    ],
)
def test_only_the_fixed_files_are_reachable(path: str) -> None:
    with live_bridge(token=TOKEN) as bridge:
        status, _, body = get(bridge, path, {"Authorization": f"Bearer {TOKEN}"})
        assert status == 404, (path, body)


def test_only_get_is_served() -> None:
    with live_bridge() as bridge:
        for method in ("POST", "PUT", "DELETE"):
            assert get(bridge, "/", method=method)[0] == 405


def test_page_requests_do_not_take_client_slots_and_websockets_share_the_port() -> None:
    with live_bridge(max_clients=1) as bridge:
        with connect(f"ws://127.0.0.1:{bridge.port}/") as client:
            client.send('{"op":"subscribe","topic":"attention_state"}')
            bridge.deliver("attention_state", {"data": "awake"})
            assert json.loads(client.recv(timeout=10))["msg"] == {"data": "awake"}
            for _ in range(5):  # more page loads than client slots
                assert get(bridge, "/")[0] == 200
            with pytest.raises(InvalidStatus) as refused:
                connect(f"ws://127.0.0.1:{bridge.port}/")
            assert refused.value.response.status_code == 503
