"""The monitor page in headless Chromium against a real bridge server (recorded ROS side): what it
subscribes to, what it shows, what its buttons publish, escaping, the token, and reconnection."""

from __future__ import annotations

import json
import re
import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from browser_helpers import b64, jpeg, transcript, wait_page
from byc_testing import wait_for
from cdp import Browser, Page
from live_bridge import NAMESPACE, live_bridge

from by_your_command.agents.metrics import ToolCallMetrics
from by_your_command.monitor.cost import Prices
from by_your_command.monitor.summary import AgentSummary

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]

TOKEN = "page-token-51e9"
PAGE_TOPICS = {
    "prompt_transcript",
    "response_text",
    "command_status",
    "attention_state",
    "voice_activity",
    "assistant_speaking",
    "interruption_signal",
    "playback_status",
    "agent_metrics",
    "agent_summary",
    "detections",
    "camera_forwarded",
}
HOSTILE = '<img src=x onerror="window.pwned=1">Robert\'); <b>bold</b>'


def connected(page_state: str) -> str:
    return f"document.getElementById('connection').dataset.state === '{page_state}'"


def shown(element_id: str) -> str:
    return f"document.getElementById('{element_id}').getClientRects().length > 0"


def stale(element_id: str) -> str:
    return f"document.getElementById('{element_id}').dataset.stale === 'true'"


def console_entries(browser: Browser, page: Page) -> list[str]:
    """Everything the page's console got (browser messages, script logs, errors), as JSON text."""
    browser.pump()
    kinds = ("Log.entryAdded", "Runtime.consoleAPICalled", "Runtime.exceptionThrown")
    return [
        json.dumps(event["params"])
        for event in browser.events
        if event.get("sessionId") == page.session_id and event["method"] in kinds
    ]


@contextmanager
def hanging_up_port(port: int) -> Iterator[list[int]]:
    """Stands in for a bridge that is down: every connection is accepted and closed at once (so each
    reconnect attempt is seen and fails). Yields the growing list of accepted connections."""
    accepted: list[int] = []
    listener = socket.socket()
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind(("127.0.0.1", port))
    listener.listen()

    def serve() -> None:
        while True:
            try:
                connection, _ = listener.accept()
            except OSError:
                return  # closed
            accepted.append(1)
            connection.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield accepted
    finally:
        listener.close()
        thread.join(timeout=10)


def test_the_page_shows_the_robot_and_drives_it(browser: Browser, tmp_path: Path) -> None:
    with live_bridge(token=TOKEN) as bridge:
        refused = browser.new_page()
        assert refused.navigate(f"{bridge.url}/") == 401  # the bridge has a token: none, no page
        assert "token is required" in refused.evaluate("document.body.textContent")
        page = browser.new_page()  # a tab of its own: its console must stay free of errors
        assert page.navigate(f"{bridge.url}/?token={TOKEN}") == 200
        wait_page(page, connected("connected"), what="the page's WebSocket (token passed on)")
        # The token is read, then taken out of the address bar (bookmarks, screenshots, history).
        assert page.evaluate("window.location.href") == f"{bridge.url}/"
        # No camera frame yet (a profile without a camera): no empty camera panel.
        assert not page.evaluate(shown("camera-panel"))

        # It subscribes to what it shows, and to no audio topic.
        expected = {f"{NAMESPACE}/{topic}" for topic in PAGE_TOPICS}
        wait_for(lambda: bridge.graph.subscribed == expected, timeout=30, what="the page's subscriptions")
        audio = {rule.topic for rule in bridge.allow.subscribe if rule.topic_class == "audio"}
        assert audio and not {f"{NAMESPACE}/{topic}" for topic in audio} & bridge.graph.subscribed

        # Transcript: user, robot, verdicts (accepted and refused), latency; text stays text.
        bridge.deliver("prompt_transcript", {"data": "look up"})
        bridge.deliver("response_text", {"data": HOSTILE})
        bridge.deliver(
            "command_status",
            {
                "raw": "lookup",
                "command": "lookup",
                "accepted": True,
                "reason": "",
                "topic": f"{NAMESPACE}/arm_preset",
            },
        )
        bridge.deliver(
            "command_status",
            {"raw": "fly away", "command": "", "accepted": False, "reason": "unknown command"},
        )
        turn = {
            "record": "turn",
            "agent_id": "robot",
            "provider": "openai_realtime",
            "session": 1,
            "turn": 1,
            "turn_kind": "voice",
            "outcome": "completed",
            "first_audio_ms": 240.4,
            "reply_ms": 1310.0,
            "usage": {"input_audio_tokens": 1000, "output_audio_tokens": 2000},
        }
        # Any client may publish on agent_metrics: what the bridge's summary refuses is not shown.
        for forged in ({**turn, "session": -1}, {**turn, "reply_ms": "soon"}, {**turn, "turn": 1.5}):
            bridge.deliver("agent_metrics", {"data": json.dumps({**forged, "agent_id": "forged"})})
        bridge.deliver("agent_metrics", {"data": json.dumps(turn)})
        failed = {**turn, "turn": 2, "outcome": "failed", "first_audio_ms": None, "reason": "provider <lost>"}
        bridge.deliver("agent_metrics", {"data": json.dumps(failed)})
        bridge.deliver("interruption_signal", {"stream_id": "robot-1-1", "reason": "barge_in", "action": 1})
        bridge.deliver("interruption_signal", {"stream_id": "robot-1-1", "reason": "barge_in"})
        wait_for(lambda: len(transcript(page)) >= 8, timeout=30, what="eight transcript lines")
        lines = transcript(page)
        assert lines[:8] == [
            ("user", '"look up"'),
            ("robot", '"<img src=x onerror="window.pwned=1">Robert\'); <b>bold</b>"'),
            ("command", f"lookup -> {NAMESPACE}/arm_preset: accepted"),
            ("command", '"fly away" refused: unknown command'),
            ("latency", "robot: first audio 240 ms, reply generated 1310 ms (completed)"),
            ("latency", "robot: first audio –, reply generated 1310 ms (failed: provider <lost>)"),
            ("interrupt", "paused robot-1-1 (barge_in)"),  # speech over it, being judged: not counted
            ("interrupt", "cut robot-1-1 (barge_in)"),
        ], lines
        assert page.evaluate("document.querySelectorAll('#transcript img, #transcript b').length") == 0
        assert page.evaluate("window.pwned === undefined")
        assert page.evaluate("document.getElementById('interruptions').textContent") == "1"

        # When the robot stopped talking: the player's playback_status, per reply.
        def played_lines() -> list[str]:
            return [line for kind, line in transcript(page) if kind == "played"]

        playing = {"stream_id": "robot-1-1-3", "played_ms": 200, "speaking": True, "finished": False}
        old = {"stream_id": "robot-0-0-9", "played_ms": 900, "speaking": False, "finished": True}
        bridge.deliver("playback_status", old)  # the latched status of a reply the page never saw: no line
        bridge.deliver("playback_status", playing)
        bridge.deliver("playback_status", {**playing, "played_ms": 1040, "speaking": False, "finished": True})
        bridge.deliver("playback_status", {**playing, "played_ms": 1040, "speaking": False, "finished": True})
        cut = {"stream_id": "robot-1-1-4", "played_ms": 100, "speaking": True}
        bridge.deliver("playback_status", cut)
        bridge.deliver("playback_status", {**cut, "played_ms": 600, "speaking": False, "interrupted": True})
        # An agent that names its reply's stream in the turn record: the end is tied to the turn.
        named = {**turn, "turn": 5, "stream_id": "robot-1-1-5"}
        bridge.deliver("agent_metrics", {"data": json.dumps(named)})
        bridge.deliver("playback_status", {"stream_id": "robot-1-1-5", "played_ms": 2000, "finished": True})
        wait_for(lambda: len(played_lines()) >= 3, timeout=30, what="three played lines")
        played = played_lines()
        assert played[:2] == [
            "robot-1-1-3: the robot stopped talking (1.0 s of audio, finished)",
            "robot-1-1-4: the robot stopped talking (0.6 s of audio, cut off)",
        ], played
        assert re.fullmatch(
            r"robot turn 5: the robot stopped talking ≈\d+ ms after the user did "
            r"\(2\.0 s of audio, finished\)",
            played[2],
        ), played
        assert len(played) == 3, played

        # Robot state.
        bridge.deliver("attention_state", {"data": "asleep"})
        bridge.deliver("voice_activity", {"data": True})
        bridge.deliver("assistant_speaking", {"data": True})
        wait_page(page, "document.getElementById('attention').dataset.state === 'asleep'")
        wait_page(page, "document.getElementById('vad').textContent === 'speech'")
        wait_page(page, "document.getElementById('speaking').textContent === 'speaking'")

        # Agents: the summary the bridge node publishes (made here by the same code).
        summary = AgentSummary({"openai_realtime": Prices(input_audio=32.0, output_audio=64.0)})
        summary.feed(json.dumps(turn))
        bridge.deliver("agent_summary", {"data": json.dumps(summary.snapshot(agents_connected=1))})
        row = wait_page(
            page,
            "Array.from(document.querySelectorAll('#agents tbody td')).map(td => td.textContent)",
            what="the agents table",
        )
        assert row[:4] == ["robot", "openai_realtime", "in session 1", "1"], row
        assert "0.1600 USD" in row  # 1000 × 32 + 2000 × 64 per million
        assert "1000 / 2000" in row

        # Camera: the forwarded frame, with the detections drawn as boxes.
        assert not page.evaluate(shown("camera-panel"))
        bridge.deliver(
            "detections",
            {
                "data": json.dumps(
                    {
                        "stamp": 1.5,
                        "frame_id": "camera",
                        "width": 320,
                        "height": 240,
                        "detections": [
                            {
                                "label": "cup <i>",
                                "box": [40, 60, 200, 180],
                                "box_2d": [250, 125, 750, 625],
                                "score": 0.9,
                            }
                        ],
                    }
                )
            },
        )
        frame = {
            "header": {"stamp": {"sec": 1700000000, "nanosec": 0}, "frame_id": "camera"},
            "format": "jpeg",
            "data": b64(jpeg(160, 120)),
        }
        bridge.deliver("camera_forwarded", frame)
        wait_page(
            page,
            "Number(document.getElementById('camera-caption').dataset.frames) >= 1",
            what="a camera frame",
        )
        assert page.evaluate(shown("camera-panel"))
        assert (
            page.evaluate("document.getElementById('detections').textContent")
            == "cup <i> 90 % [40, 60, 200, 180]"
        )
        # The box is scaled from the 320×240 detection image to the 160×120 frame: its left edge at x=20.
        edge = page.evaluate(
            "Array.from(document.getElementById('camera').getContext('2d').getImageData(20, 60, 1, 1).data)"
        )
        inside = page.evaluate(
            "Array.from(document.getElementById('camera').getContext('2d').getImageData(5, 110, 1, 1).data)"
        )
        assert edge[0] > 200 and edge[1] > 150 and edge[2] < 80, edge  # yellow box line
        assert inside[2] > 100 and inside[0] < 100, inside  # the frame itself (blue)

        # Buttons and the text box publish what the VAD and the agents understand.
        for button in ("sleep", "wake", "mute", "unmute"):
            page.evaluate(f"document.getElementById('{button}').click()")
        page.evaluate(
            "document.getElementById('prompt-input').value = 'what time is it';"
            "document.getElementById('prompt-form').requestSubmit()"
        )
        wait_for(lambda: len(bridge.graph.published) >= 5, timeout=30, what="five publishes")
        # attention_state was last "asleep" (the buttons' publishes reached no VAD here): the prompt is
        # sent (a wake phrase would still wake the robot), and the page says it will not be answered.
        ignored = [line for kind, line in transcript(page) if kind == "ignored"]
        assert ignored == [
            '"what time is it" will not be answered: the robot is asleep: agents ignore prompts until it '
            'wakes (Wake, or a wake phrase such as "wake up")'
        ], ignored
        assert "asleep" in page.evaluate("document.getElementById('action-status').textContent")
        assert bridge.graph.published == [
            (f"{NAMESPACE}/wake_cmd", {"data": False}),
            (f"{NAMESPACE}/wake_cmd", {"data": True}),
            (f"{NAMESPACE}/voice_active", {"data": False}),
            (f"{NAMESPACE}/voice_active", {"data": True}),
            (f"{NAMESPACE}/prompt_text", {"data": "what time is it"}),
        ]
        shot = page.screenshot(tmp_path / "monitor_page.png")
        print(f"monitor page screenshot: {shot}")

        # The bridge goes away and comes back: the page reconnects and subscribes again by itself.
        bridge.restart()
        wait_page(page, connected("disconnected"), what="the page noticing the bridge left")
        wait_page(page, connected("connected"), timeout=60, what="the page reconnecting")
        wait_for(lambda: bridge.graph.subscribed == expected, timeout=30, what="subscriptions replayed")
        bridge.deliver("attention_state", {"data": "muted"})
        wait_page(page, "document.getElementById('attention').dataset.state === 'muted'")
        browser.pump()
        assert page.errors() == []  # no script error, no CSP violation


def rows(page: Page, table: str) -> list[list[str]]:
    return page.evaluate(
        f"Array.from(document.querySelectorAll('#{table} tbody tr'))"
        ".map(tr => Array.from(tr.cells).map(td => td.textContent))"
    )


def test_the_robot_actions_panel_shows_running_goals_and_how_they_ended(browser: Browser) -> None:
    clock = [100.0]
    summary = AgentSummary({}, clock=lambda: clock[0])

    def record(request_id: str, state: str, tool: str = "go_to", **fields: Any) -> None:
        text = json.dumps(
            ToolCallMetrics(
                "robot", request_id, tool, "action", '{"place": "kitchen"}', state, **fields
            ).as_dict()
        )
        summary.feed(text)
        bridge.deliver("agent_metrics", {"data": text})

    with live_bridge() as bridge:
        page = browser.new_page()
        assert page.navigate(f"{bridge.url}/") == 200
        wait_page(page, connected("connected"), what="connected")
        wait_for(lambda: len(bridge.graph.subscribed) == len(PAGE_TOPICS), timeout=30, what="subscribed")
        assert page.evaluate(shown("actions-panel"))

        record("robot-1-1", "running")
        clock[0] += 1.0
        record("robot-1-2", "running", tool=HOSTILE)
        clock[0] += 3.0
        record("robot-1-1", "running", progress="distance_remaining 2.4", elapsed_s=4.0)
        record("robot-1-3", "failed", tool="dock", elapsed_s=1.5, error="goal <b>aborted</b>")
        record("robot-1-4", "succeeded", tool="look", elapsed_s=0.4)
        bridge.deliver("agent_summary", {"data": json.dumps(summary.snapshot(agents_connected=1))})

        active = wait_page(page, "document.querySelectorAll('#active-calls tbody tr').length === 2 && 1")
        assert active
        running = rows(page, "active-calls")
        assert [row[:4] for row in running] == [
            ["robot", "go_to", '{"place": "kitchen"}', "distance_remaining 2.4"],
            ["robot", HOSTILE, '{"place": "kitchen"}', "–"],
        ], running
        assert re.fullmatch(r"\d+\.\d s", running[0][4]), running
        ended = rows(page, "recent-calls")
        assert [row[:5] for row in ended] == [
            ["robot", "look", '{"place": "kitchen"}', "✓ succeeded", "0.4 s"],
            ["robot", "dock", '{"place": "kitchen"}', "✗ failed: goal <b>aborted</b>", "1.5 s"],
        ], ended
        classes = page.evaluate(
            "Array.from(document.querySelectorAll('#recent-calls tbody tr')).map(tr => tr.cells[3].className)"
        )
        assert classes == ["outcome-good", "outcome-bad"]  # the failure is marked
        assert "2 running, 2 recently ended" in page.evaluate(
            "document.getElementById('actions-summary').textContent"
        )
        # A goal with no feedback: its time still goes on between summaries.
        wait_page(
            page,
            "document.querySelector('#active-calls tbody tr:nth-child(2) td.elapsed').textContent"
            f" !== {json.dumps(running[1][4])}",
            what="the elapsed time counting on",
        )
        # The transcript: each call's start and end (not its progress), as text.
        wait_for(
            lambda: len([line for kind, line in transcript(page) if kind == "action"]) >= 4,
            timeout=30,
            what="action lines",
        )
        assert [line for kind, line in transcript(page) if kind == "action"] == [
            'robot: go_to {"place": "kitchen"} started',
            f'robot: {HOSTILE} {{"place": "kitchen"}} started',
            'robot: dock {"place": "kitchen"} ✗ failed after 1.5 s: goal <b>aborted</b>',
            'robot: look {"place": "kitchen"} ✓ succeeded after 0.4 s',
        ]
        assert (
            page.evaluate(
                "document.querySelectorAll('#actions-panel img, #actions-panel b, #transcript img').length"
            )
            == 0
        )
        assert page.evaluate("window.pwned === undefined")

        # The goals end: no longer active, listed among the outcomes.
        record("robot-1-1", "cancelled", elapsed_s=6.0, error="safety stop")
        record("robot-1-2", "timeout", tool=HOSTILE, elapsed_s=60.0)
        bridge.deliver("agent_summary", {"data": json.dumps(summary.snapshot(agents_connected=1))})
        wait_page(
            page, "document.querySelectorAll('#recent-calls tbody tr').length === 4", what="four outcomes"
        )
        assert rows(page, "active-calls") == []
        assert [row[3] for row in rows(page, "recent-calls")][:2] == ["✗ timeout", "■ cancelled: safety stop"]
        browser.pump()
        assert page.errors() == []


def test_while_the_bridge_is_away_values_are_stale_and_the_token_is_never_printed(
    browser: Browser, tmp_path: Path
) -> None:
    with live_bridge(token=TOKEN) as bridge:
        page = browser.new_page()
        assert page.navigate(f"{bridge.url}/?token={TOKEN}") == 200
        wait_page(page, connected("connected"), what="connected")
        wait_for(lambda: len(bridge.graph.subscribed) == len(PAGE_TOPICS), timeout=30, what="subscribed")
        bridge.deliver("attention_state", {"data": "awake"})
        wait_page(page, "document.getElementById('attention').dataset.state === 'awake'")
        assert not page.evaluate(stale("attention"))

        bridge.stop()
        before = len(console_entries(browser, page))
        with hanging_up_port(bridge.port) as attempts:
            wait_page(page, connected("disconnected"), what="the page noticing the bridge left")
            # Reconnect attempts that fail (each one is logged by the browser): none may show the token.
            wait_for(
                lambda: len(attempts) >= 3 and len(console_entries(browser, page)) - before >= 2,
                timeout=60,
                what="failed reconnect attempts",
            )
            printed = console_entries(browser, page)
            assert printed[before:], "the browser logs failed attempts: this test needs them"
            assert [entry for entry in printed if TOKEN in entry] == []
            # Every live value is marked as the last known one, in words too.
            for element in ("attention", "vad", "speaking", "interruptions", "agents-connected", "agents"):
                assert page.evaluate(stale(element)), element
            assert "last known" in page.evaluate("document.getElementById('connection').textContent")
            marker = "getComputedStyle(document.getElementById('attention'), '::after').content"
            assert page.evaluate(marker) == '" (stale)"'  # said in words, not only greyed
            print(f"stale page screenshot: {page.screenshot(tmp_path / 'monitor_stale.png')}")

        bridge.start()
        wait_page(page, connected("connected"), timeout=60, what="the page reconnecting")
        wait_page(page, f"!({stale('interruptions')})", what="the page's own count goes on")
        assert page.evaluate(stale("attention"))  # until the bridge says it again
        bridge.deliver("attention_state", {"data": "asleep"})
        wait_page(page, "document.getElementById('attention').dataset.state === 'asleep'")
        assert not page.evaluate(stale("attention"))
        assert [entry for entry in console_entries(browser, page) if TOKEN in entry] == []
