"""Headless Chromium driven over the Chrome DevTools Protocol with the `websockets` sync client.

No selenium or driver binary: chromium itself listens for DevTools on a loopback port it picks
(`--remote-debugging-port=0`, announced on stderr), and this speaks CDP's JSON-RPC to it.
"""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from websockets.sync.client import ClientConnection, connect

CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",  # tests run as root in a container
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--window-size=1280,1000",
    "--remote-debugging-port=0",
)
_DEVTOOLS = re.compile(r"DevTools listening on (ws://\S+)")


def chromium_binary() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


class CdpError(AssertionError):
    pass


class Page:
    """One tab: navigate, evaluate JavaScript, screenshot. Keeps the page's JS errors and console."""

    def __init__(self, browser: Browser, session_id: str) -> None:
        self._browser = browser
        self.session_id = session_id

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        return self._browser.call(method, params, self.session_id)

    def navigate(self, url: str, timeout: float = 30.0) -> int | None:
        """Loads `url`; returns the document's HTTP status (None if none arrived)."""
        mark = len(self._browser.events)
        result = self.call("Page.navigate", url=url)
        if result.get("errorText"):
            raise CdpError(f"navigation to {url} failed: {result['errorText']}")
        self._browser.wait_event(lambda e: e["method"] == "Page.loadEventFired", mark, timeout)
        for event in self._browser.events[mark:]:
            if (
                event.get("method") == "Network.responseReceived"
                and event["params"].get("type") == "Document"
            ):
                return int(event["params"]["response"]["status"])
        return None

    def evaluate(self, expression: str) -> Any:
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in result:
            raise CdpError(f"{expression!r} raised: {result['exceptionDetails']}")
        return result["result"].get("value")

    def screenshot(self, path: Path) -> Path:
        data = self.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)["data"]
        path.write_bytes(base64.b64decode(data))
        return path

    def errors(self) -> list[str]:
        """Uncaught exceptions and console errors of this page (CSP violations included)."""
        found = []
        for event in self._browser.events:
            if event.get("sessionId") != self.session_id:
                continue
            if event["method"] == "Runtime.exceptionThrown":
                found.append(json.dumps(event["params"]["exceptionDetails"])[:500])
            elif event["method"] == "Log.entryAdded" and event["params"]["entry"]["level"] == "error":
                found.append(event["params"]["entry"].get("text", "")[:500])
        return found

    def console(self) -> list[str]:
        return [
            str(event["params"]["entry"].get("text", ""))
            for event in self._browser.events
            if event.get("sessionId") == self.session_id and event["method"] == "Log.entryAdded"
        ]


class Browser:
    def __init__(self, socket: ClientConnection) -> None:
        self._socket = socket
        self._next_id = 0
        self._lock = threading.Lock()
        self.events: list[dict[str, Any]] = []

    def call(self, method: str, params: dict[str, Any] | None = None, session_id: str | None = None) -> Any:
        with self._lock:
            self._next_id += 1
            request: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
            if session_id:
                request["sessionId"] = session_id
            self._socket.send(json.dumps(request))
            deadline = time.monotonic() + 30
            while True:
                message = self._receive(deadline)
                if message.get("id") == request["id"]:
                    if "error" in message:
                        raise CdpError(f"{method}: {message['error']}")
                    return message.get("result", {})

    def _receive(self, deadline: float) -> dict[str, Any]:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise CdpError("no answer from chromium")
        message: dict[str, Any] = json.loads(self._socket.recv(timeout=remaining))
        if "method" in message:
            self.events.append(message)
        return message

    def wait_event(self, matches: Any, since: int, timeout: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while True:
            for event in self.events[since:]:
                if matches(event):
                    return event
            with self._lock:
                try:
                    self._receive(deadline)
                except TimeoutError:
                    raise CdpError("timed out waiting for a DevTools event") from None

    def pump(self) -> None:
        """Read the events that arrived meanwhile (without waiting)."""
        with self._lock:
            while True:
                try:
                    self._receive(time.monotonic() + 0.001)
                except (TimeoutError, CdpError):
                    return

    def new_page(self) -> Page:
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        page = Page(self, session)
        for domain in ("Page", "Runtime", "Log", "Network"):
            page.call(f"{domain}.enable")
        return page


@contextmanager
def headless_chromium(binary: str) -> Iterator[Browser]:
    profile = tempfile.mkdtemp(prefix="byc-chromium-")
    process = subprocess.Popen(
        [binary, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "about:blank"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stderr is not None
        seen: list[str] = []
        url = None
        deadline = time.monotonic() + 60
        while url is None:  # chromium prints the DevTools address first thing (blocking read: no sleep)
            line = process.stderr.readline()
            if not line or time.monotonic() > deadline:
                raise CdpError("chromium did not start:\n" + "".join(seen[-20:]))
            seen.append(line)
            if match := _DEVTOOLS.search(line):
                url = match.group(1)
        threading.Thread(target=_drain, args=(process,), daemon=True).start()
        with connect(url, max_size=64 * 1024 * 1024, open_timeout=30) as socket:
            yield Browser(socket)
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        shutil.rmtree(profile, ignore_errors=True)


def _drain(process: subprocess.Popen[str]) -> None:
    """Keep reading chromium's stderr so it never blocks on a full pipe."""
    assert process.stderr is not None
    for _ in process.stderr:
        pass
