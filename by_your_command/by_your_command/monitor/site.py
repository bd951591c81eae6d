"""The monitor's routes: the page, its script and style (package data), and its settings as JSON.

The page and its settings need the token (when the bridge has one); the script and the style are the
same public code for everyone and carry no robot data, so the page can load them without putting the
token in their URLs.
"""

from __future__ import annotations

import json
from importlib import resources

from by_your_command.bridge.static_files import StaticFile, StaticSite
from by_your_command.monitor.config import MonitorConfig

PAGE_PATHS = ("/", "/monitor")  # the page links its files relatively: no trailing-slash variant
CONFIG_PATH = "/monitor-config.json"
_ASSETS = {
    "/monitor.js": ("monitor.js", "text/javascript; charset=utf-8"),
    "/records.js": ("records.js", "text/javascript; charset=utf-8"),
    "/monitor.css": ("monitor.css", "text/css; charset=utf-8"),
}


def _static(name: str) -> bytes:
    return (resources.files("by_your_command.monitor") / "static" / name).read_bytes()


def monitor_site(config: MonitorConfig) -> StaticSite:
    page = StaticFile(_static("index.html"), "text/html; charset=utf-8")
    routes = {path: page for path in PAGE_PATHS}
    for path, (name, content_type) in _ASSETS.items():
        routes[path] = StaticFile(_static(name), content_type, public=True)
    settings = json.dumps(config.for_page(), separators=(",", ":")).encode()
    routes[CONFIG_PATH] = StaticFile(settings, "application/json")
    return StaticSite(routes)
