/* global L */
/* What the operator does: select a responder, place a checkpoint fix where the map is clicked
   or at a named checkpoint, and name a new checkpoint. Each action is confirmed in the dialog
   and sent to the console server (POST /api/fix, /api/checkpoint), which publishes it to the
   service under the logged-in operator's name. The service answers each with an audit ("audit" messages): a
   refusal, or a fix taken but flagged as further than a person can walk, shows as a notice
   and on the responder (S.flags). The SELECTED panel shows the selected responder and enables
   the actions that apply. */
import {S} from "./state.js";
import {$, MOTION_LABELS, ask, setText, toast} from "./ui.js";
import {postJSON} from "./api.js";
import {onMessage} from "./connection.js";
import {ellipseAxes} from "./map/projection.js";
import {centreOn, map} from "./map/view.js";
import {drawCheckpoints, setFloor} from "./map/floors.js";
import {responderAt} from "./map/responders.js";
import {renderPhoneButtons} from "./phones.js";

let addMode = false, pin = null, onSelect = () => {};

/** Select a responder (null: none); centre: show it on its floor. */
export function select(id, centre = false) {
  S.selected = id;
  const r = S.responders.get(id);
  if (centre && r && r.pose) {
    if (r.pose.floor !== S.floor && S.plans[r.pose.floor]) setFloor(r.pose.floor);
    centreOn(r.pose.x, r.pose.y);
  }
  S.dirty = true;
  renderSelection();
  onSelect();
}

export function renderSelection() {
  const r = S.selected ? S.responders.get(S.selected) : null;
  setText($("sel-id"), S.selected || "none");
  renderPhoneButtons();
  $("btn-fix-cp").disabled = !r || !$("cp-select").value;
  const flag = r ? S.flags[r.id] : null;
  $("sel-flag").hidden = !flag;
  if (flag) {
    setText($("sel-flag"), `⚠ FIX FLAGGED: ${flag.operator || flag.actor} moved ${flag.responder} ` +
            `${Math.round(flag.jump_m)} m; at most ${Math.round(flag.walkable_m)} m was walkable`);
  }
  if (!r) { setText($("sel-info"), "Click a marker or a roster row."); return; }
  const p = r.pose, s = r.status, parts = [];
  if (p) {
    parts.push(`floor ${p.floor}`, `x ${p.x.toFixed(1)} m`, `y ${p.y.toFixed(1)} m`, `heading ${Math.round(p.heading_deg)}°`,
               `±${ellipseAxes(p.cov)[0].toFixed(1)} m`, p.source);  // the 95 % ellipse's semi-major axis
  } else {
    parts.push("no position yet (not placed)");
  }
  if (s) parts.push(MOTION_LABELS[s.motion] || s.motion, `${s.frames} frames`);
  setText($("sel-info"), parts.join(" · "));
}

/** A yellow cross where the operator is about to act (null: none). */
function showPin(x, y) {
  if (pin) { pin.remove(); pin = null; }
  if (x === null) return;
  pin = L.marker(S.plans[S.floor].toLatLng(x, y), {
    interactive: false, keyboard: false, zIndexOffset: 10000,
    icon: L.divIcon({className: "pin", iconSize: null, html: "<div></div>"}),
  }).addTo(map);
}

async function send(url, body, done, failed) {
  try { toast(done(await postJSON(url, body)), "ok"); } catch (e) { toast(`${failed}: ${e.message}`, "error"); }
}

async function fixAtPoint(x, y) {
  const id = S.selected, f = S.floors.find((q) => q.number === S.floor);
  showPin(x, y);
  const ok = await ask(`Place ${id} here?`,
    `Checkpoint fix for ${id} at x ${x.toFixed(2)} m, y ${y.toFixed(2)} m on floor ${S.floor} (${f.name}). ` +
    `The service corrects ${id}'s track to this point at its latest device time.`);
  showPin(null);
  if (ok) await send("/api/fix", {responder: id, x, y, floor: S.floor},
                     (res) => `Fix sent for ${id} (device time ${res.sent.t.toFixed(1)} s)`, `Fix for ${id} not sent`);
}

async function fixAtCheckpoint() {
  const id = S.selected, name = $("cp-select").value;
  if (!id || !name) return;
  const ok = await ask(`Place ${id} at ${name}?`, `Checkpoint fix for ${id} at the named checkpoint ${name}.`);
  if (ok) await send("/api/fix", {responder: id, name}, () => `Fix sent for ${id} at ${name}`, `Fix for ${id} not sent`);
}

async function addCheckpointAt(x, y) {
  setAddMode(false);
  showPin(x, y);
  const name = await ask("Name this checkpoint",
    `New checkpoint at x ${x.toFixed(2)} m, y ${y.toFixed(2)} m on floor ${S.floor}.`, "");
  showPin(null);
  if (name) await send("/api/checkpoint", {name, x, y, floor: S.floor}, () => `Checkpoint ${name} added`, "Checkpoint not added");
}

export function setAddMode(on) {
  addMode = on;
  $("btn-add-cp").classList.toggle("on", on);
  $("mode-hint").hidden = !on;
  $("mode-hint").textContent = on ? "CLICK THE MAP WHERE THE NEW CHECKPOINT IS (Esc cancels)" : "";
}

export function fillCheckpointList() {
  const sel = $("cp-select"), cur = sel.value;
  sel.innerHTML = "";
  const none = document.createElement("option");
  none.value = ""; none.textContent = S.checkpoints.length ? "— named checkpoint —" : "no checkpoints";
  sel.appendChild(none);
  for (const c of S.checkpoints) {
    const o = document.createElement("option");
    o.value = c.name; o.textContent = `${c.name} (floor ${c.floor})`;
    sel.appendChild(o);
  }
  sel.value = S.checkpoints.some((c) => c.name === cur) ? cur : "";
  renderSelection();
}

/** A click on the map at ENU (x, y), container point `point`: a new checkpoint, a selection or a fix. */
export function onMapClick(x, y, point) {
  if (addMode) { addCheckpointAt(x, y); return; }
  const hit = responderAt(point);
  if (hit) { select(hit); return; }
  if (S.session && S.session.role === "viewer") return;  // viewers look; they do not place fixes
  if (S.mode !== "live") { toast("Fixes are placed in LIVE mode", "error"); return; }
  if (!S.selected) { toast("Select a responder first: click a marker or a roster row", "error"); return; }
  fixAtPoint(x, y);
}

const ACTION_WORDS = {fix: "fix", checkpoint: "checkpoint", ack: "acknowledgement", par: "roll call",
                      evacuate: "evacuation order", device_fix: "fix"};

function onAudit(a) {
  const who = a.operator ? `${a.operator} (${a.actor})` : a.actor;
  if (a.outcome === "refused") {
    toast(`The service refused the ${ACTION_WORDS[a.action]} by ${who}${a.responder ? ` for ${a.responder}` : ""}: ` +
          `${a.reason}${a.detail ? ` — ${a.detail}` : ""}`, "error");
  } else if ((a.flags || []).includes("implausible_jump")) {
    S.flags[a.responder] = a;
    toast(`⚠ Fix for ${a.responder} by ${who} taken but FLAGGED: ${Math.round(a.jump_m)} m from where ` +
          `${a.responder} was, at most ${Math.round(a.walkable_m)} m walkable`, "error");
    renderSelection();
  } else if (a.action === "fix" && S.flags[a.responder]) {
    delete S.flags[a.responder];  // a plausible fix since: the flag is history (it stays in the recording)
    renderSelection();
  }
}

/** afterSelect(): what else shows the selection (the roster) refreshes. */
export function bindActions(afterSelect) {
  onSelect = afterSelect;
  $("btn-fix-cp").onclick = fixAtCheckpoint;
  $("cp-select").onchange = () => renderSelection();
  $("btn-add-cp").onclick = () => setAddMode(!addMode);
  onMessage("audit", (m) => onAudit(m.audit));
  onMessage("checkpoints", (m) => { S.checkpoints = m.checkpoints; fillCheckpointList(); drawCheckpoints(); });
  onMessage("fix", (m) => {
    const f = m.fix;
    const where = f.name ? `checkpoint ${f.name}` : `(${f.x.toFixed(1)}, ${f.y.toFixed(1)}) m, floor ${f.floor}`;
    toast(`Fix for ${f.responder} at ${where} sent by ${f.operator || "the console"}`, "ok");
  });
}
