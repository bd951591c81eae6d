"""One rule for `agent_metrics` records: monitor/records.py (the bridge's summary) and the page's
static/records.js accept the same texts and read the same values from them, checked on the same
cases (edges built from records.py's limits) and on seeded mutations of real records."""

from __future__ import annotations

import json
import random
from typing import Any

import pytest
from browser_helpers import wait_page
from cdp import Browser
from live_bridge import live_bridge

from by_your_command.monitor.records import (
    MAX_ARGUMENTS_CHARS,
    MAX_COUNT,
    MAX_DEPTH,
    MAX_RECORD_CHARS,
    MAX_REQUEST_ID_CHARS,
    MAX_STREAM_ID_CHARS,
    BadRecord,
    Record,
    SessionOpenRecord,
    SessionRecord,
    ToolCallRecord,
    TurnRecord,
    parse_record,
)

TURN: dict[str, Any] = {
    "record": "turn",
    "agent_id": "robot",
    "conversation_id": "c1",
    "provider": "openai_realtime",
    "session": 1,
    "turn": 2,
    "turn_kind": "voice",
    "outcome": "completed",
    "first_audio_ms": 240.4,
    "reply_ms": 1310.0,
    "usage": {"input_audio_tokens": 1000, "output_audio_tokens": 2000, "input_tokens": 1000},
    "reason": "",
    "stream_id": "robot-1-1-2",
}
SESSION: dict[str, Any] = {
    "record": "session",
    "agent_id": "robot",
    "provider": "gemini_live",
    "session": 1,
    "billed_s": 12.5,
    "turns": 3,
    "close_reason": "idle",
    "usage": {"input_text_tokens": 5, "cached_input_tokens": 2},
}
OPENED: dict[str, Any] = {"record": "session_open", "agent_id": "robot", "provider": "offline", "session": 4}
CALL: dict[str, Any] = {
    "record": "tool_call",
    "agent_id": "robot",
    "request_id": "robot-1-7",
    "tool": "go_to",
    "kind": "action",
    "arguments": '{"place": "kitchen"}',
    "state": "running",
    "progress": "distance_remaining 2.4",
    "elapsed_s": 5.2,
    "error": "",
}


def with_fields(base: dict[str, Any], **changes: Any) -> str:
    return json.dumps({**base, **changes})


def without(base: dict[str, Any], key: str) -> str:
    return json.dumps({k: v for k, v in base.items() if k != key})


def padded_to(length: int, unit: str = "x") -> str:
    """A valid turn record of exactly `length` characters (code points), padded in an extra field."""
    bare = len(with_fields(TURN, pad=""))
    return json.dumps({**TURN, "pad": unit * (length - bare)}, ensure_ascii=False)


def nested(depth: int) -> str:
    """A turn record whose objects and lists nest `depth` deep (the record itself is level 1)."""
    return with_fields(TURN, extra=json.loads("[" * (depth - 1) + "]" * (depth - 1)))


# (what, text, accepted by the bridge's summary)
CASES: list[tuple[str, str, bool]] = [
    ("an agent's turn", json.dumps(TURN), True),
    ("an agent's closed session", json.dumps(SESSION), True),
    ("an agent's opened session", json.dumps(OPENED), True),
    (
        "a turn of an older agent: no reason, no stream",
        json.dumps({k: TURN[k] for k in TURN if k not in ("reason", "stream_id")}),
        True,
    ),
    (
        "a failed turn with its reason",
        with_fields(TURN, outcome="failed", reason="  provider\tlost\u2028 it "),
        True,
    ),
    ("no first audio", with_fields(TURN, first_audio_ms=None), True),
    ("no first audio field", without(TURN, "first_audio_ms"), True),
    ("null reason and stream", with_fields(TURN, reason=None, stream_id=None), True),
    ("the largest count", with_fields(TURN, turn=MAX_COUNT), True),
    ("a count too large", with_fields(TURN, turn=MAX_COUNT + 1), False),
    ("a count written as a float", with_fields(TURN, session=1.0), False),
    (
        "a count in exponent form",
        '{"record":"turn","agent_id":"a","session":1e0,"turn":1,"outcome":"x","reply_ms":1}',
        False,
    ),
    ("a negative count", with_fields(TURN, session=-1), False),
    ("minus zero is an integer", '{"record":"session_open","agent_id":"a","session":-0}', True),
    ("a boolean count", with_fields(TURN, turn=True), False),
    ("a negative latency", with_fields(TURN, first_audio_ms=-1), False),
    ("a latency as text", with_fields(TURN, reply_ms="1310"), False),
    ("no reply_ms", without(TURN, "reply_ms"), False),
    ("null reply_ms", with_fields(TURN, reply_ms=None), False),
    ("an infinite latency", json.dumps(TURN).replace('"reply_ms": 1310.0', '"reply_ms": 1e400'), False),
    (
        "a 400-digit latency",
        json.dumps(TURN).replace('"reply_ms": 1310.0', '"reply_ms": ' + "9" * 400),
        False,
    ),
    ("NaN", json.dumps(TURN).replace('"reply_ms": 1310.0', '"reply_ms": NaN'), False),
    ("Infinity", json.dumps(TURN).replace('"reply_ms": 1310.0', '"reply_ms": Infinity'), False),
    ("billed seconds as an integer", with_fields(SESSION, billed_s=12), True),
    ("no billed seconds", without(SESSION, "billed_s"), False),
    ("no close reason", without(SESSION, "close_reason"), False),
    ("no outcome", without(TURN, "outcome"), False),
    ("an outcome that is a number", with_fields(TURN, outcome=5), False),
    ("a reason that is not text", with_fields(TURN, reason={"html": "<b>"}), False),
    ("a stream id that is not text", with_fields(TURN, stream_id=7), False),
    ("the longest stream id", with_fields(TURN, stream_id="s" * MAX_STREAM_ID_CHARS), True),
    (
        "the longest stream id, astral",
        json.dumps({**TURN, "stream_id": "😀" * MAX_STREAM_ID_CHARS}, ensure_ascii=False),
        True,
    ),
    ("a stream id too long", with_fields(TURN, stream_id="s" * (MAX_STREAM_ID_CHARS + 1)), False),
    ("no agent id", without(TURN, "agent_id"), False),
    ("a blank agent id", with_fields(TURN, agent_id=" \t "), False),
    ("an agent id of Python whitespace only", with_fields(TURN, agent_id="\x1c\x85\u3000"), False),
    ("a zero-width no-break space is not whitespace", with_fields(TURN, agent_id="\ufeff"), True),
    ("an agent id that is not text", with_fields(TURN, agent_id=5), False),
    ("a long agent id is cut, not refused", with_fields(TURN, agent_id=" robot\n" * 40), True),
    ("a null provider", with_fields(TURN, provider=None), False),
    ("no provider", without(TURN, "provider"), True),
    ("unknown record kind", with_fields(TURN, record="bogus"), False),
    ("no record kind", without(TURN, "record"), False),
    ("null usage", with_fields(TURN, usage=None), False),
    ("usage as a list", with_fields(TURN, usage=[]), False),
    ("usage as a number", with_fields(SESSION, usage=1.5), False),
    ("a fractional token count", with_fields(TURN, usage={"input_audio_tokens": 1.5}), False),
    ("a negative token count", with_fields(TURN, usage={"output_text_tokens": -1}), False),
    ("a provider's billed seconds", with_fields(SESSION, usage={"session_s": 61.25}), True),
    ("billed seconds that are text", with_fields(SESSION, usage={"session_s": "61"}), False),
    ("negative billed seconds", with_fields(SESSION, usage={"session_s": -1}), False),
    ("absurd billed seconds", with_fields(SESSION, usage={"session_s": 1e300}), False),
    ("unknown usage keys are ignored", with_fields(TURN, usage={"input_tokens": "x"}), True),
    ("an opened session's usage is not read", with_fields(OPENED, usage="junk"), True),
    (
        "duplicate keys: the last one counts",
        '{"agent_id":5,"agent_id":"a","record":"session_open","session":1}',
        True,
    ),
    ("a __proto__ key", '{"__proto__":{"x":1},"record":"session_open","agent_id":"a","session":1}', True),
    ("as long as allowed", padded_to(MAX_RECORD_CHARS), True),
    ("as long as allowed, astral", padded_to(MAX_RECORD_CHARS, "😀"), True),
    ("one character too long", padded_to(MAX_RECORD_CHARS + 1), False),
    ("nested as deep as allowed", nested(MAX_DEPTH), True),
    ("nested one level too deep", nested(MAX_DEPTH + 1), False),
    (
        "nested beyond Python's recursion limit",
        with_fields(TURN, pad=0).replace('"pad": 0', '"pad": ' + "[" * 20000 + "]" * 20000),
        False,
    ),
    ("not JSON", "{'record': 'turn'}", False),
    ("empty", "", False),
    ("a byte order mark first", "\ufeff" + json.dumps(OPENED), False),
    ("an array", "[1, 2]", False),
    ("a number", "3", False),
    ("null", "null", False),
    ("hostile HTML as the agent", with_fields(TURN, agent_id='<img src=x onerror="window.pwned=1">'), True),
    # Robot tool calls: no provider nor session; known kinds and states only.
    ("a running tool call", json.dumps(CALL), True),
    (
        "an ended tool call with its error",
        with_fields(CALL, state="failed", progress="", error="goal\naborted  by <nav2>"),
        True,
    ),
    (
        "a started tool call: no progress nor error",
        json.dumps({k: v for k, v in CALL.items() if k not in ("progress", "error")}),
        True,
    ),
    ("null progress and error", with_fields(CALL, progress=None, error=None), True),
    ("a tool call with a bogus provider is still read", with_fields(CALL, provider=5, session="x"), True),
    *[(f"a call {state}", with_fields(CALL, state=state), True) for state in ("published", "timeout")],
    *[(f"a {kind} call", with_fields(CALL, kind=kind), True) for kind in ("service", "topic", "command")],
    ("an unknown state", with_fields(CALL, state="exploded"), False),
    ("a state in capitals", with_fields(CALL, state="RUNNING"), False),
    ("a state that is a list", with_fields(CALL, state=["running"]), False),
    ("an unknown kind", with_fields(CALL, kind="rocket"), False),
    ("a kind that is an object key", with_fields(CALL, kind="toString"), False),
    ("no state", without(CALL, "state"), False),
    ("no request id", without(CALL, "request_id"), False),
    ("an empty request id", with_fields(CALL, request_id=""), False),
    ("a request id that is a number", with_fields(CALL, request_id=7), False),
    ("the longest request id", with_fields(CALL, request_id="r" * MAX_REQUEST_ID_CHARS), True),
    ("a request id too long", with_fields(CALL, request_id="r" * (MAX_REQUEST_ID_CHARS + 1)), False),
    ("no tool", without(CALL, "tool"), False),
    ("a blank tool", with_fields(CALL, tool="  "), False),
    ("no arguments", without(CALL, "arguments"), False),
    ("arguments as an object", with_fields(CALL, arguments={"place": "kitchen"}), False),
    ("long arguments are cut", with_fields(CALL, arguments="x" * (MAX_ARGUMENTS_CHARS * 3)), True),
    ("progress that is not text", with_fields(CALL, progress=2.4), False),
    ("an error that is not text", with_fields(CALL, error={"html": "<b>"}), False),
    ("no elapsed time", without(CALL, "elapsed_s"), False),
    ("a negative elapsed time", with_fields(CALL, elapsed_s=-0.5), False),
    ("elapsed time as text", with_fields(CALL, elapsed_s="5"), False),
    ("an infinite elapsed time", json.dumps(CALL).replace('"elapsed_s": 5.2', '"elapsed_s": 1e400'), False),
    ("NaN elapsed", json.dumps(CALL).replace('"elapsed_s": 5.2', '"elapsed_s": NaN'), False),
    ("hostile HTML as the tool", with_fields(CALL, tool='<img src=x onerror="window.pwned=1">'), True),
]

# Values the mutations put in place of a field: each is a limit, a type confusion or an edge.
ODD_VALUES: list[Any] = [
    None, True, False, -1, 0, 1, 2.5, 3.0, MAX_COUNT, MAX_COUNT + 1, float(MAX_COUNT), 10**400, "", " ",
    "\x1f", "\ufeff", "x" * 70, "a\u2028b", [], {}, [[[]]], {"input_audio_tokens": 1}, "turn", "session",
    "session_open", "s" * (MAX_STREAM_ID_CHARS + 1), "tool_call", "running", "failed", "action",
]  # fmt: skip


def mutations(count: int = 400, seed: int = 33) -> list[str]:
    """Real records with fields replaced, removed, or the text cut: deterministic (seeded)."""
    rng = random.Random(seed)
    texts = []
    for _ in range(count):
        record = json.loads(json.dumps(rng.choice([TURN, SESSION, OPENED, CALL])))
        for _ in range(rng.randint(1, 3)):
            target = (
                record["usage"]
                if "usage" in record and isinstance(record["usage"], dict) and rng.random() < 0.3
                else record
            )
            key = rng.choice([*target.keys(), "input_image_tokens", "reason", "stream_id", "record"])
            if rng.random() < 0.2:
                target.pop(key, None)
            else:
                target[key] = rng.choice(ODD_VALUES)
        text = json.dumps(record)
        if rng.random() < 0.1:
            text = text[: rng.randrange(len(text))]
        texts.append(text)
    return texts


def python_view(text: str) -> list[Any] | None:
    """What records.py reads from `text` (None: refused), in the shape the page test returns."""
    try:
        record: Record = parse_record(text)
    except BadRecord:
        return None
    if isinstance(record, ToolCallRecord):
        return ["tool_call", *[getattr(record, name) for name in TOOL_CALL_FIELDS]]
    view: list[Any] = [record.agent_id, record.provider, record.session]
    if isinstance(record, SessionOpenRecord):
        return ["session_open", *view]
    tokens = vars(record.tokens)
    if isinstance(record, SessionRecord):
        return ["session", *view, record.billed_s, record.turns, record.close_reason, tokens]
    assert isinstance(record, TurnRecord)
    details = [
        record.turn,
        record.outcome,
        record.first_audio_ms,
        record.reply_ms,
        record.reason,
        record.stream_id,
    ]
    return ["turn", *view, *details, tokens]


TOOL_CALL_FIELDS = (
    "agent_id",
    "request_id",
    "tool",
    "kind",
    "arguments",
    "state",
    "progress",
    "elapsed_s",
    "error",
)

PAGE_VIEW = f"""
(texts) => texts.map((text) => {{
  const r = window.bycRecords.parseRecord(text);
  if (r === null) return null;
  if (r.record === "tool_call") return ["tool_call", ...{json.dumps(TOOL_CALL_FIELDS)}.map((k) => r[k])];
  const view = [r.agent_id, r.provider, r.session];
  if (r.record === "session_open") return ["session_open", ...view];
  if (r.record === "session") return ["session", ...view, r.billed_s, r.turns, r.close_reason, r.tokens];
  return ["turn", ...view, r.turn, r.outcome, r.first_audio_ms, r.reply_ms, r.reason, r.stream_id, r.tokens];
}})
"""


@pytest.mark.unit
@pytest.mark.parametrize(("what", "text", "accepted"), CASES, ids=[case[0] for case in CASES])
def test_records_py_takes_exactly_what_an_agent_sends(what: str, text: str, accepted: bool) -> None:
    assert (python_view(text) is not None) is accepted, what


@pytest.mark.e2e
@pytest.mark.timeout(120)
def test_the_page_reads_records_by_the_same_rules(browser: Browser) -> None:
    texts = [text for _, text, _ in CASES] + mutations()
    expected = [python_view(text) for text in texts]
    assert 20 < sum(view is not None for view in expected) < len(texts) - 20  # both sides exercised
    with live_bridge() as bridge:
        page = browser.new_page()
        assert page.navigate(f"{bridge.url}/") == 200
        wait_page(page, "typeof window.bycRecords === 'object'", what="records.js loaded")
        seen = json.loads(page.evaluate(f"JSON.stringify(({PAGE_VIEW})({json.dumps(texts)}))"))
    differences = [
        (what, page_view, python)
        for what, page_view, python in zip(
            [case[0] for case in CASES] + [f"mutation {text[:120]}" for text in texts[len(CASES) :]],
            seen,
            expected,
            strict=True,
        )
        if page_view != python
    ]
    assert differences == [], differences[:10]
