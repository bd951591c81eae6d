"""Plain HTTP GETs on the bridge's port: a fixed set of in-memory files (the monitor page).

No file system access per request and no path joining: a request path either is one of the routes
or gets 404, so `/../` and friends cannot reach anything. Every answer carries headers that keep the
page from being framed, sniffed or given foreign scripts (CSP `default-src 'self'`, no inline code).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from http import HTTPStatus
from urllib.parse import urlsplit

from websockets.datastructures import Headers
from websockets.http11 import Response

MAX_FILE_BYTES = 1_048_576  # the site is loaded into memory once: bound each file

# connect-src 'self' covers ws:// to the same host and port (CSP level 3). Images: camera frames
# are decoded from blob: URLs. Nothing inline, nothing from elsewhere, never inside a frame.
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
    "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
)
SECURITY_HEADERS = (
    ("Content-Security-Policy", CONTENT_SECURITY_POLICY),
    ("X-Content-Type-Options", "nosniff"),
    ("X-Frame-Options", "DENY"),  # frame-ancestors for older browsers
    ("Referrer-Policy", "no-referrer"),  # the page's URL may hold the token
    ("Cache-Control", "no-store"),
    ("Cross-Origin-Opener-Policy", "same-origin"),
    ("Cross-Origin-Resource-Policy", "same-origin"),
)


@dataclass(frozen=True)
class StaticFile:
    body: bytes
    content_type: str
    public: bool = False  # served without the token: code the same for everyone, no robot data

    def __post_init__(self) -> None:
        if len(self.body) > MAX_FILE_BYTES:
            raise ValueError(f"a static file of {len(self.body)} bytes (at most {MAX_FILE_BYTES})")


class StaticSite:
    """Exact paths → files. Query strings (`?token=`) are not part of the route."""

    def __init__(self, routes: Mapping[str, StaticFile]) -> None:
        for path in routes:
            if not path.startswith("/") or "?" in path or "#" in path:
                raise ValueError(f"route {path!r}: an absolute path without query")
        self._routes = dict(routes)

    def find(self, request_path: str) -> StaticFile | None:
        return self._routes.get(urlsplit(request_path).path)

    @property
    def paths(self) -> list[str]:
        return sorted(self._routes)


def is_websocket_upgrade(headers: Headers) -> bool:
    """A WebSocket handshake (Upgrade: websocket), as opposed to a plain page request."""
    return any(
        token.strip().lower() == "websocket"
        for value in headers.get_all("Upgrade")
        for token in value.split(",")
    )


def file_response(file: StaticFile) -> Response:
    return _response(HTTPStatus.OK, file.content_type, file.body)


def error_response(status: HTTPStatus, text: str) -> Response:
    return _response(status, "text/plain; charset=utf-8", text.encode())


def _response(status: HTTPStatus, content_type: str, body: bytes) -> Response:
    headers = Headers([("Content-Type", content_type), ("Content-Length", str(len(body))), *SECURITY_HEADERS])
    return Response(status.value, status.phrase, headers, body)
