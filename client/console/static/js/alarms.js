/* Alarms: what each responder's Status carries (man_down, lost_contact, par_unanswered,
   flooding, ...), plus lost_contact when the console itself has heard nothing of a responder for
   lost_contact_s (the service could be the one that is gone).

   One compact row per responder, with all of that responder's alarms, most severe first;
   rows sorted by severity, then by how long they have lasted. So twenty people in alarm take
   twenty short lines, and the bar scrolls instead of covering the map. How long an alarm has
   lasted is the service's clock (Status.alarms_since), not the page's.

   Life of an alarm (one per responder and kind, S.alarms): raised, it flashes until
   acknowledged (ACK acknowledges the row: all its alarms); acknowledged, it stays listed while
   it lasts; when it ends after acknowledgement it leaves; a new occurrence raises it again. An
   acknowledgement is also sent to the service (POST /api/ack), which records who made it. */
import {S, serverNow} from "./state.js";
import {$, ago, setText, toast} from "./ui.js";
import {select} from "./actions.js";
import {postJSON} from "./api.js";

const SEVERITY = ["man_down", "evacuation_unacknowledged", "par_unanswered", "lost_contact", "disconnected",
                  "track_degraded", "fixes_refused", "stream_contested", "rejected_frames", "flooding",
                  "recording_failed"];
const LABELS = {man_down: "MAN DOWN", lost_contact: "LOST CONTACT", rejected_frames: "BAD DATA",
                disconnected: "WEARABLE OFF", par_unanswered: "NO PAR", evacuation_unacknowledged: "NOT EVACUATING",
                flooding: "FLOODING", recording_failed: "NOT RECORDING", stream_contested: "STREAM CONTESTED",
                track_degraded: "TRACK DEGRADED", fixes_refused: "FIX REFUSED"};
const rank = (kind) => { const i = SEVERITY.indexOf(kind); return i < 0 ? SEVERITY.length : i; };

/** The alarms each responder has now, by "id|kind", with when they began (service clock). */
function current(now) {
  const active = new Map();
  for (const r of S.responders.values()) {
    const s = r.status, since = (s && s.alarms_since) || {};
    const kinds = new Map((s ? s.alarms : []).map((k) => [k, since[k] ?? now]));
    if (r.lastRx && now - r.lastRx > S.settings.lost_contact_s && !kinds.has("lost_contact")) {
      kinds.set("lost_contact", r.lastRx + S.settings.lost_contact_s);  // the console has heard nothing itself
    }
    for (const [k, t] of kinds) active.set(`${r.id}|${k}`, {responder: r.id, kind: k, since: t});
  }
  return active;
}

/** Raise new alarms, end the ones that stopped; then show the list. */
export function evaluateAlarms() {
  const now = serverNow(), active = current(now);
  for (const [key, a] of active) {
    let e = S.alarms.get(key);
    if (!e) { e = {key, responder: a.responder, kind: a.kind, active: false, acked: false, count: 0}; S.alarms.set(key, e); }
    if (!e.active) { Object.assign(e, {active: true, acked: false, count: e.count + 1, raisedAt: a.since}); S.dirty = true; }
    else e.raisedAt = a.since;
  }
  for (const e of [...S.alarms.values()]) {
    if (e.active && !active.has(e.key)) {
      e.active = false; e.clearedAt = now; S.dirty = true;
      if (e.acked) S.alarms.delete(e.key);
    }
  }
  renderAlarms(now);
}

export function acknowledge(key) {
  const e = S.alarms.get(key);
  if (!e) return;
  // the service records who acknowledged what (an operator action); the page does not wait for it
  if (!e.acked) {
    postJSON("/api/ack", {responder: e.responder, alarm: e.kind})
      .catch((err) => toast(`Acknowledgement of ${e.responder} not recorded: ${err.message}`, "error"));
  }
  e.acked = true;
  if (!e.active) S.alarms.delete(key);
  S.dirty = true;
  renderAlarms(serverNow());
}

/** Acknowledge every alarm of one responder (the row's button). */
export function acknowledgeResponder(id) {
  for (const e of [...S.alarms.values()]) if (e.responder === id) acknowledge(e.key);
}

function row(id) {
  const el = document.createElement("div");
  el.dataset.responder = id;
  el.innerHTML = '<span class="who"></span><span class="kinds"></span><span class="when"></span>' +
                 '<button class="ack">ACK</button>';
  el.querySelector(".ack").addEventListener("click", () => acknowledgeResponder(id));
  el.querySelector(".who").addEventListener("click", () => select(id, true));
  return el;
}

export function renderAlarms(now) {
  const box = $("alarms");
  const by = new Map();
  for (const a of S.alarms.values()) (by.get(a.responder) || by.set(a.responder, []).get(a.responder)).push(a);
  const groups = [...by.entries()].map(([id, list]) => {
    list.sort((a, b) => rank(a.kind) - rank(b.kind));
    return {id, list, top: rank(list[0].kind), acked: list.every((a) => a.acked),
            since: Math.min(...list.map((a) => a.raisedAt))};
  });
  groups.sort((a, b) => (a.acked - b.acked) || (a.top - b.top) || (a.since - b.since) || a.id.localeCompare(b.id));
  box.hidden = groups.length === 0;
  const keep = new Set(groups.map((g) => g.id));
  for (const el of [...box.children]) if (!keep.has(el.dataset.responder)) el.remove();
  groups.forEach((g, i) => {
    const el = box.querySelector(`[data-responder="${CSS.escape(g.id)}"]`) || row(g.id);
    if (box.children[i] !== el) box.insertBefore(el, box.children[i] || null);
    el.className = "alarm " + (g.acked ? "acked" : "flashing");
    el.dataset.kinds = g.list.map((a) => a.kind).join(" ");
    const r = S.responders.get(g.id);
    setText(el.querySelector(".who"), g.id);
    const kinds = el.querySelector(".kinds");
    const text = g.list.map((a) => (LABELS[a.kind] || a.kind.toUpperCase()) + (a.active ? "" : " (cleared)")).join(" · ");
    setText(kinds, text);
    const floor = r && r.pose ? `floor ${r.pose.floor} · ` : "";
    setText(el.querySelector(".when"), `${floor}for ${ago(now - g.since)}`);
  });
}
