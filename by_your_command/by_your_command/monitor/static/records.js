// `agent_metrics` records read back from untrusted JSON text: the page's copy of monitor/records.py.
// Any bridge client may publish on the topic, so the page shows only what the bridge's summary
// would count. Same rules, same limits; test/monitor/test_record_rules.py runs both on the same
// cases (and on seeded mutations of them), so the two cannot drift apart unnoticed.
"use strict";

window.bycRecords = (() => {
  const MAX_RECORD_CHARS = 65536;
  const MAX_NAME_CHARS = 64;
  const MAX_REASON_CHARS = 200;
  const MAX_STREAM_ID_CHARS = 200;
  const MAX_REQUEST_ID_CHARS = 200;
  const MAX_ARGUMENTS_CHARS = 200;
  const TOOL_KINDS = ["action", "service", "topic", "command"];
  const TOOL_STATES = ["running", "succeeded", "failed", "rejected", "cancelled", "timeout", "refused", "unavailable", "published"];
  const MAX_COUNT = 1e12;
  const MAX_DEPTH = 8;
  const USAGE_FIELDS = {
    input_text_tokens: "input_text",
    input_audio_tokens: "input_audio",
    input_image_tokens: "input_image",
    cached_input_tokens: "cached_input",
    output_text_tokens: "output_text",
    output_audio_tokens: "output_audio",
  };
  // Python's str.isspace() set (what split() and strip() use), not JavaScript's \s.
  const PY_SPACE = "\\t\\n\\x0b\\x0c\\r\\x1c-\\x1f \\x85\\xa0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000";
  const SPACES = new RegExp(`[${PY_SPACE}]+`, "g");
  const EDGES = new RegExp(`^[${PY_SPACE}]+|[${PY_SPACE}]+$`, "g");

  class BadRecord extends Error {}

  // Python's json keeps 3 and 3.0 apart (int, float): a count must be an integer literal.
  class JsonFloat {
    constructor(value) {
      this.value = value;
    }
  }

  function reviver(key, value, context) {
    if (typeof value !== "number") return value;
    // Without source text access (older browsers) an integral float counts as an integer.
    const source = context && typeof context.source === "string" ? context.source : null;
    return source !== null && !/^-?\d+$/.test(source) ? new JsonFloat(value) : value;
  }

  function longerThan(s, limit) {
    return s.length > limit && Array.from(s).length > limit; // Python counts code points, not UTF-16 units
  }

  function tooDeep(value, depth) {
    if (value === null || typeof value !== "object" || value instanceof JsonFloat) return false;
    if (depth > MAX_DEPTH) return true;
    return Object.values(value).some((child) => tooDeep(child, depth + 1));
  }

  function has(data, key) {
    return Object.prototype.hasOwnProperty.call(data, key);
  }

  function get(data, key) {
    return has(data, key) ? data[key] : undefined;
  }

  function flatten(value, limit) {
    return Array.from(value.replace(EDGES, "").replace(SPACES, " ")).slice(0, limit).join("");
  }

  function name(data, key, required) {
    const value = has(data, key) ? data[key] : "";
    if (typeof value !== "string" || (required && value.replace(EDGES, "") === "")) {
      throw new BadRecord(required ? `${key}: expected a non-empty string` : `${key}: expected a string`);
    }
    return flatten(value, MAX_NAME_CHARS);
  }

  function textField(data, key, limit) {
    const value = get(data, key);
    if (typeof value !== "string") throw new BadRecord(`${key}: expected a string`);
    return flatten(value, limit);
  }

  function optionalText(data, key, limit) {
    const value = get(data, key);
    return value === undefined || value === null ? "" : textField(data, key, limit);
  }

  function streamId(data) {
    const value = get(data, "stream_id");
    if (value === undefined || value === null) return "";
    if (typeof value !== "string" || longerThan(value, MAX_STREAM_ID_CHARS)) {
      throw new BadRecord(`stream_id: expected a string of at most ${MAX_STREAM_ID_CHARS} characters`);
    }
    return value;
  }

  function requestId(data) {
    const value = get(data, "request_id");
    if (typeof value !== "string" || value === "" || longerThan(value, MAX_REQUEST_ID_CHARS)) {
      throw new BadRecord(`request_id: expected a string of 1..${MAX_REQUEST_ID_CHARS} characters`);
    }
    return value;
  }

  function oneOf(data, key, allowed) {
    const value = get(data, key);
    if (typeof value !== "string" || !allowed.includes(value)) throw new BadRecord(`${key}: expected one of ${allowed.join(", ")}`);
    return value;
  }

  function toolCall(data, agentId) {
    return {
      record: "tool_call",
      agent_id: agentId,
      request_id: requestId(data),
      tool: name(data, "tool", true),
      kind: oneOf(data, "kind", TOOL_KINDS),
      arguments: textField(data, "arguments", MAX_ARGUMENTS_CHARS),
      state: oneOf(data, "state", TOOL_STATES),
      progress: optionalText(data, "progress", MAX_REASON_CHARS),
      elapsed_s: number(data, "elapsed_s"),
      error: optionalText(data, "error", MAX_REASON_CHARS),
    };
  }

  function count(data, key) {
    const value = get(data, key);
    if (typeof value !== "number" || !Number.isInteger(value) || !(value >= 0 && value <= MAX_COUNT)) {
      throw new BadRecord(`${key}: expected an integer 0..${MAX_COUNT}`);
    }
    return value;
  }

  function number(data, key) {
    const raw = get(data, key);
    const value = raw instanceof JsonFloat ? raw.value : raw;
    if (typeof value !== "number") throw new BadRecord(`${key}: expected a number`);
    if (!(value >= 0 && value <= MAX_COUNT)) throw new BadRecord(`${key}: expected a number 0..${MAX_COUNT}`);
    return value;
  }

  function millis(data, key, optional) {
    const value = get(data, key);
    if (optional && (value === undefined || value === null)) return null;
    return number(data, key);
  }

  function tokens(usage) {
    if (usage === null || typeof usage !== "object" || Array.isArray(usage) || usage instanceof JsonFloat) {
      throw new BadRecord("usage: expected an object");
    }
    const values = {};
    try {
      for (const [key, field] of Object.entries(USAGE_FIELDS)) {
        values[field] = has(usage, key) ? count(usage, key) : 0;
      }
      values.session_s = has(usage, "session_s") ? number(usage, "session_s") : 0; // a per-second provider's count
    } catch (error) {
      throw new BadRecord(`usage.${error.message}`);
    }
    return values;
  }

  function parse(text) {
    if (typeof text !== "string") throw new BadRecord("not a string");
    if (longerThan(text, MAX_RECORD_CHARS)) throw new BadRecord(`record of more than ${MAX_RECORD_CHARS} characters`);
    let data;
    try {
      data = JSON.parse(text, reviver);
    } catch (error) {
      throw new BadRecord("not JSON");
    }
    if (data === null || typeof data !== "object" || Array.isArray(data) || data instanceof JsonFloat) {
      throw new BadRecord("not a JSON object");
    }
    if (tooDeep(data, 1)) throw new BadRecord(`nested deeper than ${MAX_DEPTH} levels`);
    const kind = get(data, "record");
    const agentId = name(data, "agent_id", true);
    if (kind === "tool_call") return toolCall(data, agentId); // carries no provider nor session
    const base = { agent_id: agentId, provider: name(data, "provider", false), session: count(data, "session") };
    if (kind === "session_open") return { record: kind, ...base };
    const usage = tokens(has(data, "usage") ? data.usage : {});
    if (kind === "turn") {
      return {
        record: kind,
        ...base,
        turn: count(data, "turn"),
        outcome: textField(data, "outcome", MAX_NAME_CHARS),
        first_audio_ms: millis(data, "first_audio_ms", true),
        reply_ms: millis(data, "reply_ms", false),
        tokens: usage,
        reason: optionalText(data, "reason", MAX_REASON_CHARS),
        stream_id: streamId(data),
      };
    }
    if (kind === "session") {
      return {
        record: kind,
        ...base,
        billed_s: number(data, "billed_s"),
        turns: count(data, "turns"),
        close_reason: textField(data, "close_reason", MAX_REASON_CHARS),
        tokens: usage,
      };
    }
    throw new BadRecord("record must be 'turn', 'session', 'session_open' or 'tool_call'");
  }

  // The record (normalised like records.py), or null for anything the bridge would not count.
  function parseRecord(text) {
    try {
      return parse(text);
    } catch (error) {
      if (error instanceof BadRecord || error instanceof RangeError) return null; // RangeError: too deep
      throw error;
    }
  }

  return Object.freeze({ parseRecord });
})();
