/* The wearable page (/wear): enrol, choose where the phone is carried, track, answer orders.
   Everything the page does is in window.__wear for the tests and for a curious officer. */
import {FrameCutter} from "./motion.js";
import {Link} from "./link.js";
import {ManDownPrompt} from "./prompt.js";
import {ScreenLock, startMotion, watchPosition} from "./sensors.js";

const $ = (id) => document.getElementById(id);
const FLUSH_MS = 200;  // a frame in progress goes out when the sensors are quiet this long
const GAP_S = 0.5;  // samples further apart than this are a gap, shown on the page
const STORE = "firetrack.wear.";
const LABELS = {par: "ROLL CALL", evacuate: "EVACUATE"};
const TEXTS = {par: "Confirm you are accounted for.", evacuate: "Leave the building now by the nearest safe exit."};

const W = window.__wear = {
  ready: false, tracking: false, responder: localStorage.getItem(STORE + "responder"),
  token: localStorage.getItem(STORE + "token"), carry: localStorage.getItem(STORE + "carry") || "hand",
  samples: 0, frames: 0, gaps: [], fixes: 0, orders: [], acks: 0, state: null, problems: [],
  link: null, api: null, prompt: null,
};
const device = localStorage.getItem(STORE + "device") || `phone-${hex(6)}`;
localStorage.setItem(STORE + "device", device);
const boot = hex(8);  // this start of the page: one stream of seq numbers
const cutter = W.cutter = new FrameCutter();
const screen = new ScreenLock();
let motion = null, stopFix = null, flushTimer = null, lastSampleT = null, hiddenAt = null;

function hex(n) { return [...crypto.getRandomValues(new Uint8Array(n))].map((b) => b.toString(16).padStart(2, "0")).join(""); }
function problem(text) { W.problems.push(text); $("problem").textContent = text; }
function setLink(text, cls) { $("link").textContent = text; $("link").className = `state ${cls}`; }

// ---------------------------------------------------------------- enrolment
async function claim(code) {
  $("enrol-error").textContent = "";
  const res = await fetch("/wear/claim", {method: "POST", headers: {"Content-Type": "application/json"},
                                          body: JSON.stringify({code})});
  const body = await res.json().catch(() => ({error: `${res.status}`}));
  if (!res.ok) { $("enrol-error").textContent = body.error; return; }
  W.token = body.token; W.responder = body.responder;
  localStorage.setItem(STORE + "token", W.token);
  localStorage.setItem(STORE + "responder", W.responder);
  history.replaceState(null, "", "/wear");
  showTracking();
}

function showTracking() {
  $("enrol").hidden = true; $("track").hidden = false;
  $("who").textContent = W.responder;
  W.link = new Link({url: `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/wear/ws`,
                     token: W.token, device, boot, onEvent: linkEvent});
  W.link.start();
  setCarry(W.carry);
}

function showEnrol(why) {
  $("track").hidden = true; $("enrol").hidden = false;
  if (why) $("enrol-error").textContent = why;
}

// ---------------------------------------------------------------- the link's news
function linkEvent(type, m) {
  if (type === "welcome") setLink(W.tracking ? "CONNECTED" : "READY", "ok");
  else if (type === "down") setLink(W.tracking ? "OFFLINE — KEEPING DATA" : "NOT CONNECTED", "bad");
  else if (type === "revoked") { stop(); localStorage.removeItem(STORE + "token"); showEnrol("This phone's enrolment was revoked: ask the console for a new code."); }
  else if (type === "refused") problem(`refused: ${m.detail}`);
  else if (type === "state") {
    W.state = m;
    $("sigma").textContent = m.sigma_m == null ? "—" : `${m.sigma_m.toFixed(1)} m`;
    $("steps").textContent = String(m.steps);
    if (W.tracking && W.link.ready) setLink(m.heard ? "CONNECTED · HEARD" : "CONNECTED · NO SERVICE", m.heard ? "ok" : "wait");
    W.prompt.update(m);
  } else if (type === "command") order(m);
  if (type === "welcome") for (const c of m.commands || []) order({type: "command", ...c});
  render();
}

function render() {
  const l = W.link;
  if (!l) return;
  $("acked").textContent = l.acked == null ? "0" : String(l.acked + 1);
  $("pending").textContent = String(l.pending);
}

// ---------------------------------------------------------------- tracking
function setCarry(c) {
  W.carry = c;
  localStorage.setItem(STORE + "carry", c);
  for (const b of document.querySelectorAll("#carry button")) b.setAttribute("aria-checked", String(b.dataset.carry === c));
}

function onSample(s) {
  W.samples++;
  if (lastSampleT != null && s.t - lastSampleT > GAP_S) gap(lastSampleT, s.t, "no sensor data");
  lastSampleT = s.t;
  const f = cutter.push(s);
  if (f) sendFrame(f);
  clearTimeout(flushTimer);
  flushTimer = setTimeout(() => { const g = cutter.flush(); if (g) sendFrame(g); }, FLUSH_MS);
}

function sendFrame(f) {
  const utc_offset = Date.now() / 1000 - performance.now() / 1000;
  W.link.frame(f, {carry: W.carry, utc_offset, responder: W.responder});
  W.frames++;
  render();
}

/** A stretch without data, said on the page as it is (the service counts it in its gaps too). */
function gap(from, to, why) {
  W.gaps.push({from, to, why});
  $("gap").hidden = false;
  $("gap").textContent = `GAP: ${why} for ${(to - from).toFixed(1)} s — not tracked then (${W.gaps.length} gap${W.gaps.length > 1 ? "s" : ""})`;
}

async function start() {
  $("problem").textContent = "";
  try {
    motion = await startMotion(onSample, problem);
  } catch (e) {
    problem(`cannot start the motion sensors: ${e.message || e}`);
    return;
  }
  W.api = motion.api;
  $("sensors").textContent = motion.api === "generic" ? (motion.magnetometer ? "ACC GYR MAG" : "ACC GYR") : "MOTION EVENTS";
  stopFix = watchPosition((fix) => { if (W.link.send({type: "fix", ...fix})) W.fixes++; }, problem);
  await screen.take();
  W.tracking = true;
  $("start").textContent = "STOP TRACKING";
  $("start").className = "big stop";
  setLink(W.link.ready ? "CONNECTED" : "CONNECTING", W.link.ready ? "ok" : "wait");
}

function stop() {
  if (motion) motion.stop();
  if (stopFix) stopFix();
  motion = stopFix = null;
  const g = cutter.flush();
  if (g) sendFrame(g);
  screen.release();
  W.tracking = false;
  $("start").textContent = "START TRACKING";
  $("start").className = "big primary";
}

document.addEventListener("visibilitychange", () => {
  const now = performance.now() / 1000;
  if (document.visibilityState === "hidden") { hiddenAt = now; return; }
  if (hiddenAt != null && W.tracking) gap(hiddenAt, now, "page hidden");
  hiddenAt = null;
  if (screen.wanted) screen.take();
});

// ---------------------------------------------------------------- orders
let beeper = null;
function order(m) {
  if (W.orders.some((o) => o.id === m.id)) return;
  W.orders.push({id: m.id, action: m.action, shown_at: Date.now() / 1000, acked_at: null});
  showOrder(m);
}

function showOrder(m) {
  $("order").className = m.action;
  $("order-title").textContent = LABELS[m.action] || m.action.toUpperCase();
  $("order-text").textContent = TEXTS[m.action] || "";
  $("order").dataset.id = m.id;
  $("order").hidden = false;
  if (navigator.vibrate) navigator.vibrate([400, 200, 400, 200, 400]);
  beeper = beeper || alarmSound();
}

function alarmSound() {
  try {
    const ctx = new AudioContext(), osc = ctx.createOscillator(), gain = ctx.createGain();
    osc.type = "square"; osc.frequency.value = 880; gain.gain.value = 0.2;
    osc.connect(gain).connect(ctx.destination); osc.start();
    return {stop: () => { osc.stop(); ctx.close(); }};
  } catch (e) { return null; }
}

$("order-ack").addEventListener("click", () => {
  const id = $("order").dataset.id, o = W.orders.find((x) => x.id === id);
  if (!W.link.send({type: "ack", id})) { $("order-text").textContent = "NOT CONNECTED — tap ACK again"; return; }
  if (o) o.acked_at = Date.now() / 1000;
  W.acks++;
  const open = W.orders.find((x) => x.acked_at == null);
  if (open) { showOrder(open); return; }
  $("order").hidden = true;
  if (beeper && $("prompt").hidden) { beeper.stop(); beeper = null; }
});

W.prompt = new ManDownPrompt({box: $("prompt"), title: $("prompt-title"), count: $("prompt-count"), ok: $("prompt-ok")},
                              (msg) => W.link != null && W.link.send(msg),
                              {alert: () => { if (navigator.vibrate) navigator.vibrate([600, 200, 600]); beeper = beeper || alarmSound(); },
                               quiet: () => { if (beeper && $("order").hidden) { beeper.stop(); beeper = null; } }});

// ---------------------------------------------------------------- battery, controls, boot
async function battery() {
  if (!navigator.getBattery) return;
  const b = await navigator.getBattery();
  const show = () => { $("battery").textContent = `${Math.round(b.level * 100)} %${b.charging ? " ⚡" : ""}`; };
  b.addEventListener("levelchange", show); show();
}

for (const b of document.querySelectorAll("#carry button")) b.addEventListener("click", () => setCarry(b.dataset.carry));
$("start").addEventListener("click", () => (W.tracking ? stop() : start()));
$("join").addEventListener("click", () => claim($("code").value));
battery();
const code = new URLSearchParams(location.hash.slice(1)).get("code");
if (code) claim(code);
else if (W.token) showTracking();
else showEnrol();
W.ready = true;
