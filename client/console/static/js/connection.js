/* The live feed: a WebSocket on /ws. The server sends a "snapshot" on connect (and after the
   page fell behind), then batched "update"s with the latest pose and status of the responders
   that changed, and notices ("checkpoints", "fix"). Every message carries the server's "now".

   A module that wants another message type registers a handler: onMessage("par", fn). */
import {S, applyPose, applyStatus, responder} from "./state.js";
import {$} from "./ui.js";
import {addSample} from "./perf.js";
import {getJSON} from "./api.js";
import {sessionEnded} from "./login.js";

const RETRY_MAX_S = 5;  // reconnect back-off grows 1 s per attempt up to this

const handlers = new Map();

/** Call fn(message) for every message of this type. */
export function onMessage(type, fn) { handlers.set(type, fn); }

onMessage("snapshot", (m) => {
  for (const [id, tr] of Object.entries(m.trails || {})) responder(id).trail = tr.slice(-S.settings.trail_points);
  for (const p of m.poses) applyPose(p, false);  // the snapshot's trails hold the latest point already
  for (const s of m.statuses) applyStatus(s);
  S.rejected = m.rejected || {};
  S.flags = m.flags || {};
  S.dirty = true;
});

onMessage("update", (m) => {
  for (const p of m.poses) applyPose(p);
  for (const s of m.statuses) applyStatus(s);
  S.rejected = m.rejected || S.rejected;
  S.dirty = true;
});

function receive(ev) {
  const t0 = performance.now();
  const m = JSON.parse(ev.data);
  S.messages++;
  if (m.now) S.clockOffset = m.now - Date.now() / 1000;
  const fn = handlers.get(m.type);
  if (fn) fn(m);
  addSample("message", performance.now() - t0);
}

function show() {
  const c = $("conn");
  c.className = "conn " + (S.connected ? "ok" : "bad");
  c.textContent = S.connected ? "● CONNECTED" : "NO CONNECTION — RETRYING";
}

let retry = 0;

/** Connect, and reconnect after a loss; the page keeps what it had meanwhile. */
export function connect() {
  const proto = location.protocol === "https:" ? "wss" : "ws";
  const ws = new WebSocket(`${proto}://${location.host}/ws`);
  ws.onopen = () => { S.connected = true; retry = 0; show(); };
  ws.onmessage = receive;
  ws.onclose = async (ev) => {
    S.connected = false; show();
    if (ev.code === 4401) { sessionEnded(); return; }  // revoked
    retry = Math.min(retry + 1, RETRY_MAX_S);
    if (retry >= 2 && S.session && S.session.auth === "required") {  // refused: is the session over?
      try { if (!(await getJSON("/api/session")).user) { sessionEnded(); return; } } catch (e) { /* server away: retry */ }
    }
    setTimeout(connect, 1000 * retry);
  };
}
