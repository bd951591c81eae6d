"""The monitor page in headless Chromium against a real bridge server (recorded ROS side): what it
subscribes to, what it shows, what its buttons publish, escaping, the token, and reconnection."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from browser_helpers import b64, jpeg, transcript, wait_page
from byc_testing import wait_for
from cdp import Browser
from live_bridge import NAMESPACE, live_bridge

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
    "agent_metrics",
    "agent_summary",
    "detections",
    "camera_forwarded",
}
HOSTILE = '<img src=x onerror="window.pwned=1">Robert\'); <b>bold</b>'


def connected(page_state: str) -> str:
    return f"document.getElementById('connection').dataset.state === '{page_state}'"


def test_the_page_shows_the_robot_and_drives_it(browser: Browser, tmp_path: Path) -> None:
    with live_bridge(token=TOKEN) as bridge:
        refused = browser.new_page()
        assert refused.navigate(f"{bridge.url}/") == 401  # the bridge has a token: none, no page
        assert "token is required" in refused.evaluate("document.body.textContent")
        page = browser.new_page()  # a tab of its own: its console must stay free of errors
        assert page.navigate(f"{bridge.url}/?token={TOKEN}") == 200
        wait_page(page, connected("connected"), what="the page's WebSocket (token passed on)")

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
        bridge.deliver("agent_metrics", {"data": json.dumps(turn)})
        bridge.deliver("interruption_signal", {"stream_id": "robot-1-1", "reason": "barge_in"})
        wait_for(lambda: len(transcript(page)) >= 6, timeout=30, what="six transcript lines")
        lines = transcript(page)
        assert lines[:6] == [
            ("user", '"look up"'),
            ("robot", '"<img src=x onerror="window.pwned=1">Robert\'); <b>bold</b>"'),
            ("command", f"lookup -> {NAMESPACE}/arm_preset: accepted"),
            ("command", '"fly away" refused: unknown command'),
            ("latency", "robot: first audio 240 ms, reply done 1310 ms (completed)"),
            ("interrupt", "robot-1-1 (barge_in)"),
        ], lines
        assert page.evaluate("document.querySelectorAll('#transcript img, #transcript b').length") == 0
        assert page.evaluate("window.pwned === undefined")
        assert page.evaluate("document.getElementById('interruptions').textContent") == "1"

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
