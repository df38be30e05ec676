/* Alarms: man_down, lost_contact, rejected_frames, disconnected and flooding from the service's Status;
   lost_contact also when the console has heard nothing of a responder for lost_contact_s.

   Life of an alarm (one per responder and kind, S.alarms): raised, it flashes until
   acknowledged; acknowledged, it stays listed while it lasts; when it ends after
   acknowledgement it leaves the list; a new occurrence raises it again (count + 1). The list
   (#alarms) shows unacknowledged alarms first, then by the time they were raised. */
import {S, serverNow} from "./state.js";
import {$, ago, setText} from "./ui.js";
import {select} from "./actions.js";

const LABELS = {man_down: "MAN DOWN", lost_contact: "LOST CONTACT", rejected_frames: "BAD DATA",
                disconnected: "WEARABLE OFF", flooding: "FLOODING", recording_failed: "NOT RECORDED"};

/** The alarms each responder has now, by "id|kind". */
function current(now) {
  const active = new Map();
  for (const r of S.responders.values()) {
    const kinds = new Set(r.status ? r.status.alarms : []);
    if (r.lastRx && now - r.lastRx > S.settings.lost_contact_s) kinds.add("lost_contact");
    for (const k of kinds) active.set(`${r.id}|${k}`, {responder: r.id, kind: k});
  }
  return active;
}

/** Raise new alarms, end the ones that stopped; then show the list. */
export function evaluateAlarms() {
  const now = serverNow(), active = current(now);
  for (const [key, a] of active) {
    let e = S.alarms.get(key);
    if (!e) { e = {key, responder: a.responder, kind: a.kind, active: false, acked: false, count: 0}; S.alarms.set(key, e); }
    if (!e.active) { Object.assign(e, {active: true, acked: false, count: e.count + 1, raisedAt: now}); S.dirty = true; }
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
  e.acked = true;
  if (!e.active) S.alarms.delete(key);
  S.dirty = true;
  renderAlarms(serverNow());
}

function row(a) {
  const el = document.createElement("div");
  el.dataset.key = a.key;
  el.dataset.responder = a.responder;
  el.dataset.kind = a.kind;
  el.innerHTML = '<span class="what"></span><span class="who"></span><span class="when"></span>' +
                 '<span class="state"></span><button class="ack">ACKNOWLEDGE</button>';
  el.querySelector(".ack").addEventListener("click", () => acknowledge(a.key));
  el.querySelector(".who").addEventListener("click", () => select(a.responder, true));
  return el;
}

export function renderAlarms(now) {
  const box = $("alarms");
  const list = [...S.alarms.values()].sort((a, b) => (a.acked - b.acked) || (a.raisedAt - b.raisedAt));
  box.hidden = list.length === 0;
  const keep = new Set(list.map((a) => a.key));
  for (const el of [...box.children]) if (!keep.has(el.dataset.key)) el.remove();
  list.forEach((a, i) => {
    const el = box.querySelector(`[data-key="${CSS.escape(a.key)}"]`) || row(a);
    if (box.children[i] !== el) box.insertBefore(el, box.children[i] || null);
    el.className = "alarm " + (a.acked ? "acked" : "flashing");
    const r = S.responders.get(a.responder);
    const floor = r && r.pose ? ` · floor ${r.pose.floor}` : "";
    setText(el.querySelector(".what"), LABELS[a.kind] || a.kind.toUpperCase());
    setText(el.querySelector(".who"), a.responder);
    setText(el.querySelector(".when"), `${floor} · since ${ago(now - a.raisedAt)}` + (a.count > 1 ? ` · ${a.count}×` : ""));
    setText(el.querySelector(".state"), a.active ? (a.acked ? "ACKNOWLEDGED" : "ACTIVE") : "CLEARED");
  });
}
