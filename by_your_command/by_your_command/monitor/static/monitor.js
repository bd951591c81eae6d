// by_your_command live monitor: a small rosbridge v2 client of our own (no third-party code).
// Everything received is untrusted: fields are type-checked, and text only ever reaches the page
// through textContent (never parsed as HTML). No audio topic is subscribed.
"use strict";

(() => {
  const TOKEN = takeTokenFromAddressBar();
  const DEFAULTS = { currency: "USD", page: { camera_interval_ms: 500, transcript_lines: 300, latency_turns: 50 } };
  const BACKOFF_INITIAL_MS = 500;
  const BACKOFF_MAX_MS = 10000;
  const STABLE_AFTER_MS = 5000; // a connection that lasted this long resets the backoff
  const MAX_TEXT = 500;
  const MAX_FRAME_CHARS = 8 * 1024 * 1024; // base64 of a 6 MB image: far above a forwarded frame
  const MAX_TRACKED_STREAMS = 64; // replies followed from their turn record / first status to their end
  const MAX_ACTIVE_SHOWN = 32; // running robot tool calls per agent (the summary keeps as many)
  const RECENT_SHOWN = 10; // ended robot tool calls, all agents together, newest first
  // How a robot tool call ended, for the eye: done, stopped on purpose, or not done (marked).
  const OUTCOMES = {
    succeeded: ["good", "✓"],
    published: ["good", "✓"],
    cancelled: ["stopped", "■"],
    failed: ["bad", "✗"],
    rejected: ["bad", "✗"],
    timeout: ["bad", "✗"],
    refused: ["bad", "✗"],
    unavailable: ["bad", "✗"],
  };

  // topic -> [type, options]; every topic the page shows (none of them audio).
  const SUBSCRIPTIONS = {
    prompt_transcript: ["std_msgs/msg/String"],
    response_text: ["std_msgs/msg/String"],
    command_status: ["by_your_command_msgs/msg/CommandVerdict"],
    attention_state: ["std_msgs/msg/String"],
    voice_activity: ["std_msgs/msg/Bool"],
    assistant_speaking: ["std_msgs/msg/Bool"],
    interruption_signal: ["by_your_command_msgs/msg/Interruption"],
    playback_status: ["by_your_command_msgs/msg/PlaybackStatus"],
    agent_metrics: ["std_msgs/msg/String"],
    agent_summary: ["std_msgs/msg/String"],
    detections: ["std_msgs/msg/String"],
    camera_forwarded: ["sensor_msgs/msg/CompressedImage", { queue_length: 1 }],
  };
  const PUBLISHES = {
    prompt_text: "std_msgs/msg/String",
    wake_cmd: "std_msgs/msg/Bool",
    voice_active: "std_msgs/msg/Bool",
  };

  const $ = (id) => document.getElementById(id);
  const state = {
    settings: DEFAULTS,
    socket: null,
    backoffMs: BACKOFF_INITIAL_MS,
    openedAt: 0,
    interruptions: 0,
    frames: 0,
    detections: null,
    decoding: false,
    pendingFrame: null,
    lastAttention: "",
    failedAttempts: 0,
    playing: new Map(), // stream_id -> true: replies seen playing whose end is still to come
    turnsByStream: new Map(), // stream_id -> the turn record that named it (agents that send stream_id)
    callsStarted: new Map(), // request_id -> true: robot tool calls whose start line is shown
    callsAt: 0, // performance.now() when the robot actions panel was drawn (its times count on from there)
  };

  // The token is read once and taken out of the address bar (and so out of bookmarks, screenshots
  // and the history entry): it is kept in memory only, and never written to the console.
  function takeTokenFromAddressBar() {
    const url = new URL(window.location.href);
    const token = url.searchParams.get("token") || "";
    if (url.searchParams.has("token")) {
      url.searchParams.delete("token");
      window.history.replaceState(window.history.state, "", `${url.pathname}${url.search}${url.hash}`);
    }
    return token;
  }

  // --- small helpers ------------------------------------------------------------------------

  function text(value, limit = MAX_TEXT) {
    const s = typeof value === "string" ? value : String(value ?? "");
    const flat = s.replace(/\s+/g, " ").trim();
    return flat.length > limit ? flat.slice(0, limit - 1) + "…" : flat;
  }

  function isNumber(value) {
    return typeof value === "number" && Number.isFinite(value);
  }

  function ms(value) {
    return isNumber(value) ? `${Math.round(value)} ms` : "–";
  }

  function setState(id, value, label) {
    const element = $(id);
    element.dataset.state = value;
    element.textContent = label;
    fresh(id);
  }

  // While disconnected every live value is the last one known: marked, until a new one comes.
  function markStale() {
    for (const element of document.querySelectorAll("[data-live]")) element.dataset.stale = "true";
  }

  function fresh(...ids) {
    for (const id of ids) delete $(id).dataset.stale;
  }

  function remember(map, key, value) {
    map.delete(key);
    map.set(key, value);
    while (map.size > MAX_TRACKED_STREAMS) map.delete(map.keys().next().value);
  }

  function cell(row, value, className) {
    const td = document.createElement("td");
    td.textContent = value;
    if (className) td.className = className;
    row.appendChild(td);
  }

  // Our billed seconds, and the provider's own count when it reports one (it is what is priced).
  function seconds(billed, provider) {
    if (!isNumber(billed)) return "?";
    return isNumber(provider) && provider > 0 ? `${billed.toFixed(1)} (provider ${provider.toFixed(1)})` : billed.toFixed(1);
  }

  function money(value, currency) {
    return isNumber(value) ? `${value.toFixed(4)} ${currency}` : "no price";
  }

  // --- transcript ---------------------------------------------------------------------------

  function addLine(kind, message, extra = {}) {
    const list = $("transcript");
    const item = document.createElement("li");
    item.dataset.kind = kind;
    for (const [key, value] of Object.entries(extra)) item.dataset[key] = value;
    const time = document.createElement("span");
    time.className = "time";
    time.textContent = new Date().toLocaleTimeString();
    const what = document.createElement("span");
    what.className = "kind";
    what.textContent = kind;
    const body = document.createElement("span");
    body.className = "text";
    body.textContent = message;
    item.append(time, what, body);
    const atBottom = list.scrollHeight - list.scrollTop - list.clientHeight < 40;
    list.appendChild(item);
    while (list.children.length > state.settings.page.transcript_lines) list.removeChild(list.firstChild);
    if (atBottom) list.scrollTop = list.scrollHeight;
  }

  // --- handlers per topic -------------------------------------------------------------------

  function parseJsonField(msg) {
    if (typeof msg.data !== "string" || msg.data.length > 1024 * 1024) return null;
    try {
      const value = JSON.parse(msg.data);
      return value !== null && typeof value === "object" && !Array.isArray(value) ? value : null;
    } catch (error) {
      return null;
    }
  }

  const handlers = {
    prompt_transcript(msg) {
      if (typeof msg.data === "string" && msg.data.trim()) addLine("user", `"${text(msg.data)}"`);
    },
    response_text(msg) {
      if (typeof msg.data === "string" && msg.data.trim()) addLine("robot", `"${text(msg.data)}"`);
    },
    command_status(msg) {
      if (msg.accepted === true) {
        const where = text(msg.topic, 120) || "?";
        addLine("command", `${text(msg.command, 120)} -> ${where}: accepted`, { verdict: "accepted" });
      } else {
        addLine("command", `"${text(msg.raw, 120)}" refused: ${text(msg.reason, 200)}`, { verdict: "refused" });
      }
    },
    attention_state(msg) {
      const value = text(msg.data, 20);
      if (!["awake", "asleep", "muted"].includes(value)) return;
      setState("attention", value, value);
      if (value !== state.lastAttention) addLine("attention", value);
      state.lastAttention = value;
    },
    voice_activity(msg) {
      const on = msg.data === true;
      setState("vad", String(on), on ? "speech" : "silent");
    },
    assistant_speaking(msg) {
      const on = msg.data === true;
      setState("speaking", String(on), on ? "speaking" : "no");
    },
    interruption_signal(msg) {
      // action: 0 cut (the count), 1 pause (speech over the reply, being judged), 2 resume
      const action = { 1: "paused", 2: "resumed" }[msg.action] || "cut";
      if (action === "cut") {
        state.interruptions += 1;
        $("interruptions").textContent = String(state.interruptions);
        fresh("interruptions");
      }
      const stream = text(msg.stream_id, 80) || "every reply so far";
      addLine("interrupt", `${action} ${stream} (${text(msg.reason, 40) || "no reason"})`);
    },
    agent_metrics(msg) {
      // Checked by the same rules as the bridge's summary (records.js = monitor/records.py).
      const record = typeof msg.data === "string" ? window.bycRecords.parseRecord(msg.data) : null;
      if (record === null) return;
      const agent = text(record.agent_id, 40);
      if (record.record === "turn") {
        const why = text(record.reason, 160); // a failure's reason: a report, not the robot's speech
        const outcome = why ? `${text(record.outcome, 40)}: ${why}` : text(record.outcome, 40);
        // reply_ms ends when the reply is generated, not played: playback_status tells that (below).
        addLine("latency", `${agent}: first audio ${ms(record.first_audio_ms)}, reply generated ${ms(record.reply_ms)} (${outcome})`);
        if (record.stream_id) remember(state.turnsByStream, record.stream_id, { agent, record, at: performance.now() });
      } else if (record.record === "session_open") {
        addLine("session", `${agent}: session ${record.session} open`);
      } else if (record.record === "tool_call") {
        callLine(agent, record);
      } else {
        const counted = record.tokens.session_s > 0 ? `, provider ${record.tokens.session_s.toFixed(1)} s` : "";
        addLine("session", `${agent}: session closed after ${record.billed_s.toFixed(1)} s billed${counted} (${text(record.close_reason, 120)})`);
      }
    },
    playback_status(msg) {
      if (typeof msg.stream_id !== "string" || !msg.stream_id || msg.stream_id.length > 200) return;
      const stream = msg.stream_id;
      if (msg.finished !== true && msg.interrupted !== true) {
        if (msg.speaking === true && !state.playing.has(stream)) remember(state.playing, stream, true);
        return;
      }
      const turn = state.turnsByStream.get(stream);
      // A reply this page never saw playing nor announced (the latched status of an old one): skip.
      if (!state.playing.has(stream) && turn === undefined) return;
      state.playing.delete(stream);
      state.turnsByStream.delete(stream);
      const how = msg.interrupted === true ? "cut off" : "finished";
      const played = isNumber(msg.played_ms) ? `${(msg.played_ms / 1000).toFixed(1)} s of audio, ${how}` : how;
      if (turn === undefined) {
        addLine("played", `${text(stream, 80)}: the robot stopped talking (${played})`);
      } else {
        // Page arrival times of the record and of this status: the same bridge carried both.
        const afterUser = turn.record.reply_ms + (performance.now() - turn.at);
        addLine("played", `${turn.agent} turn ${turn.record.turn}: the robot stopped talking ≈${ms(afterUser)} after the user did (${played})`);
      }
    },
    agent_summary(msg) {
      const summary = parseJsonField(msg);
      if (summary !== null) showSummary(summary);
    },
    detections(msg) {
      const data = parseJsonField(msg);
      if (data === null || !Array.isArray(data.detections)) return;
      showCameraPanel();
      fresh("detections");
      state.detections = data;
      showDetections(data);
      drawOverlay();
    },
    camera_forwarded(msg) {
      if (typeof msg.data !== "string" || msg.data.length > MAX_FRAME_CHARS) return;
      const format = typeof msg.format === "string" && msg.format.toLowerCase().includes("png") ? "png" : "jpeg";
      state.pendingFrame = { data: msg.data, type: `image/${format}`, stamp: msg.header && msg.header.stamp };
      if (!state.decoding) decodeNextFrame();
    },
  };

  // --- robot actions ------------------------------------------------------------------------

  function outcome(state) {
    return Object.prototype.hasOwnProperty.call(OUTCOMES, state) ? OUTCOMES[state] : ["bad", "?"];
  }

  function seconds(value) {
    return isNumber(value) ? `${value.toFixed(1)} s` : "?";
  }

  function ago(value) {
    if (!isNumber(value)) return "?";
    return value < 120 ? `${Math.round(value)} s ago` : `${Math.round(value / 60)} min ago`;
  }

  function ended(call) {
    const [, mark] = outcome(call.state);
    const error = text(call.error, 200);
    return `${mark} ${text(call.state, 20)}${error ? `: ${error}` : ""}`;
  }

  // The transcript says when a call starts and how it ends (its progress is in the panel).
  function callLine(agent, record) {
    const what = `${agent}: ${text(record.tool, 64)} ${text(record.arguments, 200)}`;
    if (record.state === "running") {
      if (state.callsStarted.has(record.request_id)) return;
      remember(state.callsStarted, record.request_id, true);
      addLine("action", `${what} started`);
      return;
    }
    state.callsStarted.delete(record.request_id);
    const after = record.elapsed_s > 0 ? ` after ${seconds(record.elapsed_s)}` : "";
    const error = record.error ? `: ${text(record.error, 200)}` : "";
    const [kind, mark] = outcome(record.state);
    addLine("action", `${what} ${mark} ${record.state}${after}${error}`, { outcome: kind });
  }

  function listOf(value, limit) {
    return Array.isArray(value) ? value.slice(0, limit).filter((item) => item !== null && typeof item === "object") : [];
  }

  function total(agents, key) {
    return agents.reduce((sum, agent) => sum + (Number.isInteger(agent[key]) && agent[key] > 0 ? agent[key] : 0), 0);
  }

  function showCalls(agents) {
    fresh("actions-summary", "active-calls", "recent-calls");
    state.callsAt = performance.now();
    const active = [];
    const recent = [];
    for (const agent of agents) {
      const id = text(agent.agent_id, 40);
      for (const call of listOf(agent.active_calls, MAX_ACTIVE_SHOWN)) active.push([id, call]);
      for (const call of listOf(agent.recent_calls, RECENT_SHOWN)) recent.push([id, call]);
    }
    const age = (call) => (isNumber(call.age_s) ? call.age_s : Infinity);
    recent.sort((a, b) => age(a[1]) - age(b[1]));
    const rows = $("active-calls").tBodies[0];
    rows.replaceChildren();
    for (const [id, call] of active) {
      const row = rows.insertRow();
      cell(row, id);
      cell(row, text(call.tool, 64), "state-running");
      cell(row, text(call.arguments, 200));
      cell(row, text(call.progress, 200) || "–");
      cell(row, seconds(call.elapsed_s), "elapsed");
      if (isNumber(call.elapsed_s)) row.lastChild.dataset.base = String(call.elapsed_s);
    }
    const ends = $("recent-calls").tBodies[0];
    ends.replaceChildren();
    for (const [id, call] of recent.slice(0, RECENT_SHOWN)) {
      const row = ends.insertRow();
      cell(row, id);
      cell(row, text(call.tool, 64));
      cell(row, text(call.arguments, 200));
      cell(row, ended(call), `outcome-${outcome(call.state)[0]}`);
      cell(row, seconds(call.elapsed_s));
      cell(row, ago(call.age_s), "ago");
      if (isNumber(call.age_s)) row.lastChild.dataset.base = String(call.age_s);
    }
    const notes = [];
    const evicted = total(agents, "calls_evicted");
    const unfinished = total(agents, "calls_unfinished");
    if (evicted > 0) notes.push(`${evicted} forgotten (too many running at once)`);
    if (unfinished > 0) notes.push(`${unfinished} never ended (their agent stopped)`);
    const counts = active.length || recent.length ? `${active.length} running, ${recent.length} recently ended` : "no robot action yet";
    $("actions-summary").textContent = [counts, ...notes].join("; ");
  }

  // Times go on between summaries (published only when something changed); not while stale.
  function tickCalls() {
    const since = (performance.now() - state.callsAt) / 1000;
    if ($("active-calls").dataset.stale === undefined) {
      for (const td of $("active-calls").querySelectorAll("td.elapsed[data-base]")) td.textContent = seconds(Number(td.dataset.base) + since);
    }
    if ($("recent-calls").dataset.stale === undefined) {
      for (const td of $("recent-calls").querySelectorAll("td.ago[data-base]")) td.textContent = ago(Number(td.dataset.base) + since);
    }
  }

  // --- agents panel -------------------------------------------------------------------------

  function showSummary(summary) {
    fresh("agents-connected", "agents", "providers", "total-cost");
    const currency = text(summary.currency, 8) || state.settings.currency;
    const connected = Number.isInteger(summary.agents_connected) ? summary.agents_connected : "?";
    const invalid = Number.isInteger(summary.invalid_records) && summary.invalid_records > 0
      ? `; ${summary.invalid_records} invalid record(s) ignored` : "";
    $("agents-connected").textContent = `${connected} agent(s) connected to the bridge${invalid}`;
    const agents = $("agents").tBodies[0];
    agents.replaceChildren();
    const shown = listOf(summary.agents, 64);
    showCalls(shown);
    for (const agent of shown) {
      const row = agents.insertRow();
      const stateName = text(agent.state, 20);
      let stateLabel = stateName;
      if (stateName === "in session" && Number.isInteger(agent.open_session)) stateLabel = `in session ${agent.open_session}`;
      else if (agent.last_close_reason) stateLabel = `${stateName} (${text(agent.last_close_reason, 80)})`;
      cell(row, text(agent.agent_id, 40));
      cell(row, text(agent.provider, 40) || "?");
      cell(row, stateLabel, `state-${stateName.replace(/[^a-z]+/g, "-")}`);
      cell(row, String(Number.isInteger(agent.turns) ? agent.turns : "?"));
      cell(row, String(Number.isInteger(agent.sessions) ? agent.sessions : "?"));
      cell(row, seconds(agent.billed_s, agent.provider_s));
      cell(row, `${agent.input_tokens ?? "?"} / ${agent.output_tokens ?? "?"}`);
      cell(row, money(agent.cost, currency));
      cell(row, `${ms(agent.last_first_audio_ms)} (${ms(agent.median_first_audio_ms)})`);
    }
    const providers = $("providers").tBodies[0];
    providers.replaceChildren();
    for (const provider of Array.isArray(summary.providers) ? summary.providers.slice(0, 16) : []) {
      if (provider === null || typeof provider !== "object") continue;
      const row = providers.insertRow();
      cell(row, text(provider.provider, 40) || "?");
      cell(row, String(Number.isInteger(provider.sessions) ? provider.sessions : "?"));
      cell(row, seconds(provider.billed_s, provider.provider_s));
      cell(row, `${provider.input_tokens ?? "?"} / ${provider.output_tokens ?? "?"}`);
      cell(row, money(provider.cost, currency));
    }
    $("total-cost").textContent = `estimated total: ${money(summary.total_cost, currency)}`;
  }

  // --- camera -------------------------------------------------------------------------------

  function base64ToBytes(data) {
    const binary = atob(data);
    const bytes = new Uint8Array(binary.length);
    for (let i = 0; i < binary.length; i += 1) bytes[i] = binary.charCodeAt(i);
    return bytes;
  }

  let lastBitmap = null;

  // Hidden until a frame or a detection comes: a profile without a camera gives its room to the
  // transcript instead of an empty black box.
  function showCameraPanel() {
    $("camera-panel").hidden = false;
    document.querySelector("main").dataset.camera = "shown";
  }

  async function decodeNextFrame() {
    state.decoding = true;
    while (state.pendingFrame !== null) {
      const frame = state.pendingFrame;
      state.pendingFrame = null; // only the newest waiting frame matters
      try {
        const bitmap = await createImageBitmap(new Blob([base64ToBytes(frame.data)], { type: frame.type }));
        if (lastBitmap !== null) lastBitmap.close();
        lastBitmap = bitmap;
        state.frames += 1;
        showCameraPanel();
        fresh("camera", "camera-caption");
        const canvas = $("camera");
        canvas.width = bitmap.width;
        canvas.height = bitmap.height;
        drawOverlay();
        const caption = $("camera-caption");
        caption.dataset.frames = String(state.frames);
        const stamp = frame.stamp && isNumber(frame.stamp.sec) ? new Date(frame.stamp.sec * 1000).toLocaleTimeString() : "?";
        caption.textContent = `${bitmap.width}×${bitmap.height}, taken ${stamp}; ${state.frames} frame(s) shown`;
      } catch (error) {
        $("camera-caption").textContent = "a camera frame could not be decoded";
      }
    }
    state.decoding = false;
  }

  function drawOverlay() {
    const canvas = $("camera");
    const context = canvas.getContext("2d");
    if (lastBitmap === null) return;
    context.drawImage(lastBitmap, 0, 0);
    const data = state.detections;
    if (data === null) return;
    // Boxes are in the pixels of the image they were found in: scale to the frame shown.
    const sx = isNumber(data.width) && data.width > 0 ? canvas.width / data.width : 1;
    const sy = isNumber(data.height) && data.height > 0 ? canvas.height / data.height : 1;
    context.lineWidth = Math.max(2, canvas.width / 320);
    context.font = `${Math.max(12, Math.round(canvas.width / 40))}px sans-serif`;
    for (const item of data.detections.slice(0, 100)) {
      if (item === null || typeof item !== "object" || !Array.isArray(item.box) || item.box.length !== 4) continue;
      if (!item.box.every(isNumber)) continue;
      const [x0, y0, x1, y1] = item.box;
      context.strokeStyle = "#ffcc00";
      context.fillStyle = "#ffcc00";
      context.strokeRect(x0 * sx, y0 * sy, (x1 - x0) * sx, (y1 - y0) * sy);
      context.fillText(text(item.label, 40), x0 * sx + 3, Math.max(12, y0 * sy - 4));
    }
  }

  function showDetections(data) {
    const list = $("detections");
    list.replaceChildren();
    for (const item of data.detections.slice(0, 100)) {
      if (item === null || typeof item !== "object") continue;
      const li = document.createElement("li");
      const score = isNumber(item.score) ? ` ${(item.score * 100).toFixed(0)} %` : "";
      const box = Array.isArray(item.box) && item.box.every(isNumber) ? ` [${item.box.map(Math.round).join(", ")}]` : "";
      li.textContent = `${text(item.label, 60)}${score}${box}`;
      list.appendChild(li);
    }
  }

  // --- the connection -----------------------------------------------------------------------
  // A failed WebSocket handshake makes the browser print its URL, which holds the token, to the
  // console. So every attempt first asks for the settings over HTTP, with the token in a header (a
  // failed request prints only "monitor-config.json"), and opens the WebSocket only once the
  // bridge answered.

  function send(message) {
    if (state.socket === null || state.socket.readyState !== WebSocket.OPEN) return false;
    state.socket.send(JSON.stringify(message));
    return true;
  }

  function onOpen() {
    state.openedAt = Date.now();
    state.failedAttempts = 0;
    setState("connection", "connected", "connected");
    fresh("interruptions"); // this page's own count: it goes on counting
    for (const [topic, [type, options]] of Object.entries(SUBSCRIPTIONS)) {
      const request = { op: "subscribe", id: `sub:${topic}`, topic, type, ...(options || {}) };
      if (topic === "camera_forwarded") request.throttle_rate = state.settings.page.camera_interval_ms;
      send(request);
    }
    for (const [topic, type] of Object.entries(PUBLISHES)) send({ op: "advertise", id: `adv:${topic}`, topic, type });
  }

  function onMessage(event) {
    if (typeof event.data !== "string") return;
    let message;
    try {
      message = JSON.parse(event.data);
    } catch (error) {
      return;
    }
    if (message === null || typeof message !== "object") return;
    if (message.op === "publish" && typeof message.topic === "string" && message.msg && typeof message.msg === "object") {
      const handler = Object.prototype.hasOwnProperty.call(handlers, message.topic) ? handlers[message.topic] : null;
      if (handler !== null) handler(message.msg);
    } else if (message.op === "status") {
      onStatus(message);
    }
  }

  function onStatus(status) {
    const code = text(status.code, 40);
    if (code === "lost" || code === "dropped") {
      const counts = status.counts && typeof status.counts === "object" ? status.counts : {};
      const what = Object.entries(counts).map(([topic, n]) => `${text(n, 12)} ${text(topic, 80)}`).join(", ");
      addLine("lost", `${code}: ${what || "messages"}`);
    } else if (status.level === "error") {
      $("action-status").textContent = `bridge: ${text(status.msg, 200)}`;
    }
  }

  function retryLater(why) {
    state.socket = null;
    if (state.openedAt && Date.now() - state.openedAt > STABLE_AFTER_MS) state.backoffMs = BACKOFF_INITIAL_MS;
    state.openedAt = 0; // set when a socket opens: a refused attempt must not reset the backoff
    state.failedAttempts += 1;
    const wait = Math.round(state.backoffMs * (0.5 + Math.random() / 2));
    state.backoffMs = Math.min(state.backoffMs * 2, BACKOFF_MAX_MS);
    markStale();
    setState("connection", "disconnected", `${why}; retrying in ${(wait / 1000).toFixed(1)} s; values shown are the last known`);
    $("connection").dataset.failedAttempts = String(state.failedAttempts);
    window.setTimeout(connect, wait);
  }

  function authorization() {
    return TOKEN ? { Authorization: `Bearer ${TOKEN}` } : {};
  }

  // The bridge's answer for the settings: true when it is up and takes the token.
  async function loadSettings() {
    let response;
    try {
      response = await fetch("monitor-config.json", { cache: "no-store", headers: authorization() });
    } catch (error) {
      return "the bridge does not answer";
    }
    if (response.status === 401) return "the bridge refused this page's token (open the page's URL with ?token= again)";
    if (!response.ok) return `the bridge answered HTTP ${response.status}`;
    try {
      applySettings(await response.json());
    } catch (error) {
      $("action-status").textContent = "settings not readable; using defaults";
    }
    return "";
  }

  function applySettings(settings) {
    const page = { ...DEFAULTS.page };
    for (const key of Object.keys(page)) {
      const value = settings && settings.page ? settings.page[key] : undefined;
      if (Number.isInteger(value) && value > 0) page[key] = value;
    }
    state.settings = { currency: text(settings && settings.currency, 8) || DEFAULTS.currency, page };
  }

  async function connect() {
    setState("connection", "connecting", "connecting…");
    const refusal = await loadSettings();
    if (refusal) {
      retryLater(refusal);
      return;
    }
    const scheme = window.location.protocol === "https:" ? "wss://" : "ws://";
    const query = TOKEN ? `?token=${encodeURIComponent(TOKEN)}` : ""; // browsers cannot set a header here
    let socket;
    try {
      socket = new WebSocket(`${scheme}${window.location.host}/${query}`);
    } catch (error) {
      retryLater("the connection could not be opened");
      return;
    }
    state.socket = socket;
    socket.addEventListener("open", onOpen);
    socket.addEventListener("message", onMessage);
    socket.addEventListener("close", () => retryLater("disconnected"));
  }

  // --- controls -----------------------------------------------------------------------------

  function publish(topic, msg, done) {
    const sent = send({ op: "publish", topic, msg });
    $("action-status").textContent = sent ? done : "not connected: nothing was sent";
    return sent;
  }

  // Agents take no prompt while the robot is asleep or muted (the VAD's attention_state): say so
  // instead of leaving the person waiting for an answer that cannot come.
  const NOT_ANSWERED = {
    asleep: "the robot is asleep: agents ignore prompts until it wakes (Wake, or a wake phrase such as \"wake up\")",
    muted: "the robot is muted: agents ignore prompts until it is unmuted (Unmute)",
  };

  function sendPrompt(value) {
    const why = Object.prototype.hasOwnProperty.call(NOT_ANSWERED, state.lastAttention) ? NOT_ANSWERED[state.lastAttention] : "";
    const quoted = `"${text(value, 80)}"`;
    if (!publish("prompt_text", { data: value }, why ? `sent ${quoted}, but ${why}` : `sent: ${quoted}`)) return;
    if (why) addLine("ignored", `${quoted} will not be answered: ${why}`);
  }

  function setupControls() {
    $("wake").addEventListener("click", () => publish("wake_cmd", { data: true }, "wake sent"));
    $("sleep").addEventListener("click", () => publish("wake_cmd", { data: false }, "sleep sent"));
    $("mute").addEventListener("click", () => publish("voice_active", { data: false }, "mute sent"));
    $("unmute").addEventListener("click", () => publish("voice_active", { data: true }, "unmute sent"));
    $("prompt-form").addEventListener("submit", (event) => {
      event.preventDefault();
      const input = $("prompt-input");
      const value = input.value.trim();
      if (!value) return;
      sendPrompt(value);
      input.value = "";
    });
  }

  setupControls();
  window.setInterval(tickCalls, 1000);
  connect();
})();
