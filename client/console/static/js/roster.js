/* The roster: one row per responder, sortable by any column (click a header; again to reverse).
   A column is one entry of COLUMNS: its header, the value it sorts by and the text it shows.
   Rows are marked .selected, .alarmed (an active alarm), .other (on another floor than the one
   shown) and .stale (not heard for STALE_S). */
import {S, alarmSets, serverNow} from "./state.js";
import {$, MOTION_LABELS, ago, setText} from "./ui.js";
import {select} from "./actions.js";

const STALE_S = 5;  // HEARD turns red after this long

const steps = (r) => Math.max(r.pose ? r.pose.steps : 0, r.status ? r.status.steps : 0);
// gaps in the responder's frames: seconds not covered and frames known lost (Status.gap_s, .lost)
const gapText = (r) => (!r.status || !r.status.gaps ? "—"
  : `${r.status.gap_s.toFixed(1)} s` + (r.status.lost ? ` / ${r.status.lost} lost` : ""));
const COLUMNS = [
  {key: "id", label: "ID", value: (r) => r.id, text: (r) => r.id},
  {key: "floor", label: "FLOOR", value: (r) => (r.pose ? r.pose.floor : -Infinity), text: (r) => (r.pose ? String(r.pose.floor) : "—")},
  {key: "heard", label: "HEARD", value: (r, now) => (r.lastRx ? now - r.lastRx : Infinity), text: (r, now) => ago(r.lastRx ? now - r.lastRx : NaN)},
  {key: "steps", label: "STEPS", value: steps, text: (r) => String(steps(r))},
  {key: "gaps", label: "GAPS", value: (r) => (r.status ? r.status.gap_s || 0 : 0), text: gapText},
  {key: "motion", label: "MOTION", value: (r) => (r.status ? r.status.motion : ""),
   text: (r) => (r.status ? MOTION_LABELS[r.status.motion] || r.status.motion : "—")},
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
                 r.pose && r.pose.floor !== S.floor ? "other" : "", !(now - r.lastRx <= STALE_S) ? "stale" : ""]
      .filter(Boolean).join(" ");
    if (tr.className !== cls) tr.className = cls;
  });
  setText($("count"), String(list.length));
  for (const th of $("roster").tHead.rows[0].cells) {
    th.classList.toggle("sorted", th.dataset.key === sort.key);
    th.classList.toggle("desc", th.dataset.key === sort.key && sort.dir < 0);
  }
}
