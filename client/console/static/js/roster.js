/* The roster: one row per responder, sortable by any column (click a header; again to reverse).
   A column is one entry of COLUMNS: its header, the value it sorts by and the text it shows.
   Every responder of the incident's roster has a row from the start, heard or not: that is
   what accountability is counted against. Rows are marked .selected, .alarmed (an active
   alarm), .other (on another floor than the one shown), .stale (the wearable's last frame
   reached the service more than STALE_S ago) and .unheard (never heard), .flagged (its latest
   checkpoint fix was an implausible jump, taken because an authorised operator sent it).

   HEARD is the time since the wearable's last frame reached the service (Status.last_heard,
   the service's clock), so it grows while a wearable is silent even though the service goes
   on reporting; MOTION is the state as of that frame, shown with a "?" once it is stale. */
import {S, alarmSets, heardAgo, serverNow} from "./state.js";
import {$, MOTION_LABELS, ago, setText} from "./ui.js";
import {select} from "./actions.js";
import {parText, parValue} from "./par.js";

const STALE_S = 5;  // HEARD turns red after this long

const steps = (r) => Math.max(r.pose ? r.pose.steps : 0, r.status ? r.status.steps : 0);
// gaps in the responder's frames: seconds not covered and frames known lost (Status.gap_s, .lost)
const gapText = (r) => (!r.status || !r.status.gaps ? "—"
  : `${r.status.gap_s.toFixed(1)} s` + (r.status.lost ? ` / ${r.status.lost} lost` : ""));
/** m: the 1-sigma radius of the position in its worst direction (the larger eigenvalue of cov). */
function sigma(r) {
  if (!r.pose) return NaN;
  const [xx, xy, yy] = r.pose.cov, m = (xx + yy) / 2, d = Math.sqrt(((xx - yy) / 2) ** 2 + xy * xy);
  return Math.sqrt(Math.max(m + d, 0));
}
/** The last fix applied: its source and how long ago (UTC, with the wearable's clock offset). */
function lastFix(r, now) {
  const f = r.status && r.status.last_fix, off = r.status && r.status.utc_offset;
  if (!f) return {text: "—", age: Infinity};
  const age = off == null ? NaN : now - (f.t + off);
  return {text: `${f.source} ${ago(age)}`, age};
}
/** The beacon this responder heard last (Status.beacons_heard: device times) and how long ago. */
function lastBeacon(r, now) {
  const heard = r.status && r.status.beacons_heard, off = r.status && r.status.utc_offset;
  const ids = heard ? Object.keys(heard) : [];
  if (!ids.length) return {text: "—", age: Infinity};
  const id = ids.reduce((a, b) => (heard[b] > heard[a] ? b : a));
  const b = S.beacons.find((q) => q.id.toUpperCase() === id.toUpperCase());
  const age = off == null ? NaN : now - (heard[id] + off);
  return {text: `${(b && b.name) || id} ${ago(age)}`, age};
}
const inside = (r, now) => (r.status && r.status.first_heard ? now - r.status.first_heard : NaN);
const motion = (r, now) => {
  if (!r.status) return "—";
  const m = MOTION_LABELS[r.status.motion] || r.status.motion;
  return heardAgo(r, now) > S.settings.lost_contact_s ? `${m}?` : m;
};

const COLUMNS = [
  {key: "id", label: "ID", value: (r) => r.id, text: (r) => r.id},
  {key: "team", label: "TEAM", value: (r) => (r.member && r.member.team) || "", text: (r) => (r.member && r.member.team) || "—"},
  {key: "role", label: "ROLE", value: (r) => (r.member && r.member.role) || "", text: (r) => (r.member && r.member.role) || "—"},
  {key: "floor", label: "FLOOR", value: (r) => (r.pose ? r.pose.floor : -Infinity), text: (r) => (r.pose ? String(r.pose.floor) : "—")},
  {key: "sigma", label: "±M", value: (r) => (r.pose ? sigma(r) : Infinity), text: (r) => (r.pose ? sigma(r).toFixed(1) : "—")},
  {key: "heard", label: "HEARD", value: (r, now) => (r.status ? heardAgo(r, now) : Infinity), text: (r, now) => ago(heardAgo(r, now))},
  {key: "motion", label: "MOTION", value: (r) => (r.status ? r.status.motion : ""), text: motion},
  {key: "fix", label: "LAST FIX", value: (r, now) => lastFix(r, now).age, text: (r, now) => lastFix(r, now).text},
  {key: "beacon", label: "BEACON", value: (r, now) => lastBeacon(r, now).age, text: (r, now) => lastBeacon(r, now).text},
  {key: "inside", label: "IN BLDG", value: (r, now) => inside(r, now) || -1, text: (r, now) => ago(inside(r, now))},
  {key: "steps", label: "STEPS", value: steps, text: (r) => String(steps(r))},
  {key: "gaps", label: "GAPS", value: (r) => (r.status ? r.status.gap_s || 0 : 0), text: gapText},
  {key: "par", label: "PAR", value: parValue, text: parText},
];

let sort = {key: "id", dir: 1};
const rows = new Map();  // id -> <tr>

export function bindRoster() {
  const head = $("roster").tHead.rows[0];
  for (const c of COLUMNS) {
    const th = document.createElement("th");
    th.dataset.key = c.key;
    th.textContent = c.label;
    th.onclick = () => { sort = {key: c.key, dir: sort.key === c.key ? -sort.dir : 1}; renderRoster(); };
    head.appendChild(th);
  }
}

function newRow(id) {
  const tr = document.createElement("tr");
  tr.dataset.id = id;
  for (const c of COLUMNS) tr.appendChild(document.createElement("td")).className = c.key;
  tr.addEventListener("click", () => select(id, true));
  rows.set(id, tr);
  return tr;
}

export function renderRoster() {
  const now = serverNow(), tbody = $("roster").tBodies[0];
  const col = COLUMNS.find((c) => c.key === sort.key), list = [...S.responders.values()];
  list.sort((a, b) => {
    const va = col.value(a, now), vb = col.value(b, now);
    const c = typeof va === "string" ? va.localeCompare(vb, undefined, {numeric: true}) : va - vb;
    return sort.dir * (c || a.id.localeCompare(b.id, undefined, {numeric: true}));
  });
  for (const [id, tr] of rows) if (!S.responders.has(id)) { tr.remove(); rows.delete(id); }
  const al = alarmSets();
  list.forEach((r, i) => {
    const tr = rows.get(r.id) || newRow(r.id);
    if (tbody.children[i] !== tr) tbody.insertBefore(tr, tbody.children[i] || null);
    COLUMNS.forEach((c, j) => setText(tr.children[j], c.text(r, now)));
    const cls = [r.id === S.selected ? "selected" : "", al.active.has(r.id) ? "alarmed" : "",
                 r.pose && r.pose.floor !== S.floor ? "other" : "", heardAgo(r, now) > STALE_S ? "stale" : "",
                 r.status ? "" : "unheard", parText(r) === "MISSING" ? "par-missing" : "",
                 S.flags[r.id] ? "flagged" : ""]
      .filter(Boolean).join(" ");
    if (tr.className !== cls) tr.className = cls;
  });
  setText($("count"), String(list.length));
  for (const th of $("roster").tHead.rows[0].cells) {
    th.classList.toggle("sorted", th.dataset.key === sort.key);
    th.classList.toggle("desc", th.dataset.key === sort.key && sort.dir < 0);
  }
}
