"""Static routing: exact paths only, bounded files, and telling page requests from handshakes."""

from __future__ import annotations

import pytest
from websockets.datastructures import Headers

from by_your_command.bridge.static_files import MAX_FILE_BYTES, StaticFile, StaticSite, is_websocket_upgrade
from by_your_command.monitor.config import MonitorConfig
from by_your_command.monitor.site import monitor_site

pytestmark = pytest.mark.unit


def test_routes_are_exact_paths_and_ignore_the_query() -> None:
    page = StaticFile(b"<html>", "text/html")
    site = StaticSite({"/": page, "/a.js": StaticFile(b"x", "text/javascript", public=True)})
    assert site.find("/?token=abc") is page
    assert site.find("/a.js?v=1#x") is not None
    for path in ("/a.js/", "/A.JS", "/../a.js", "/./a.js", "//a.js", "/a.js%00", "a.js", ""):
        assert site.find(path) is None, path


def test_a_site_refuses_bad_routes_and_oversized_files() -> None:
    with pytest.raises(ValueError, match="absolute path"):
        StaticSite({"a.js": StaticFile(b"", "text/javascript")})
    with pytest.raises(ValueError, match="absolute path"):
        StaticSite({"/?x": StaticFile(b"", "text/javascript")})
    with pytest.raises(ValueError, match="at most"):
        StaticFile(b"x" * (MAX_FILE_BYTES + 1), "text/plain")


def test_the_monitor_site_serves_a_fixed_set_and_only_code_is_public() -> None:
    site = monitor_site(MonitorConfig())
    assert site.paths == [
        "/",
        "/monitor",
        "/monitor-config.json",
        "/monitor.css",
        "/monitor.js",
        "/records.js",
    ]
    public = {path for path in site.paths if (found := site.find(path)) is not None and found.public}
    assert public == {"/monitor.css", "/monitor.js", "/records.js"}


@pytest.mark.parametrize(
    ("headers", "upgrade"),
    [
        ([("Upgrade", "websocket"), ("Connection", "Upgrade")], True),
        ([("Upgrade", "WebSocket")], True),
        ([("Upgrade", "h2c, websocket")], True),
        ([("Upgrade", "h2c")], False),
        ([], False),
    ],
)
def test_page_requests_are_told_from_websocket_handshakes(
    headers: list[tuple[str, str]], upgrade: bool
) -> None:
    assert is_websocket_upgrade(Headers(headers)) is upgrade
