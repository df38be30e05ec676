/* firetrack console page: ES modules, no build step, works offline (Leaflet is vendored).

     state.js        the store S (window.__firetrack) and the live data it holds
     connection.js   the WebSocket feed: snapshot, updates, notices by message type
     api.js          the HTTP API (GET, POST JSON)
     login.js        who is at the keyboard: the login form, the header's user, LOG OUT
     ui.js           DOM helpers, toasts, the confirmation dialog
     perf.js         draw and frame times
     map/            projection.js frames and ellipses; view.js the Leaflet map, fit, north, scale;
                     floors.js plans, grids, checkpoints, floor buttons; grid.js the metre grid;
                     responders.js markers, labels, trails, ellipses
     roster.js       the responder table
     alarms.js       alarms and their acknowledgement, one row per responder (sent to the service, recorded with who)
     par.js          roll call (PAR) and evacuation order (recorded with the operator who issued it)
     actions.js      selection, checkpoint fixes, new checkpoints, the service's audits and flags
     review.js       the review slider over the smoothed tracks

   Data: the login first (GET /api/session), then GET /api/incident once (floors, checkpoints, plans with their pixel -> ENU maps), then
   the WebSocket. This module starts everything and runs the animation-frame loop. */
import {S, frame, seedRoster, serverNow, serviceBehind} from "./state.js";
import {$, bindModal, modalOpen, setText, toast} from "./ui.js";
import {getJSON} from "./api.js";
import {connect} from "./connection.js";
import {login} from "./login.js";
import {frameTick, perfStats, resetPerf} from "./perf.js";
import {bearingToScreen, ellipseAxes, ellipseOutline} from "./map/projection.js";
import {centreOn, createMap, enuToScreen, fit, fitResponders, map, screenToEnu} from "./map/view.js";
import {buildFloors, renderFloorButtons, setFloor} from "./map/floors.js";
import {drawResponders, flashPhase, initResponders} from "./map/responders.js";
import {bindRoster, renderRoster} from "./roster.js";
import {evaluateAlarms} from "./alarms.js";
import {bindPar} from "./par.js";
import {bindPhones} from "./phones.js";
import {bindActions, fillCheckpointList, onMapClick, renderSelection, select, setAddMode} from "./actions.js";
import {bindReview, reviewPositions, setReviewOffset} from "./review.js";

const PANELS_PERIOD_MS = 500;  // roster, floor buttons, selection: "heard ... s ago" changes anyway
const ALARM_PERIOD_MS = 500;
const CLOCK_PERIOD_MS = 1000;

/** Where each responder is drawn now: its live pose, or its track at the review time. */
function positions() {
  if (S.mode === "review" && S.review) return reviewPositions();
  const out = [];
  for (const r of S.responders.values()) {
    const p = r.pose;
    if (p) out.push({id: r.id, x: p.x, y: p.y, floor: p.floor, heading: p.heading_deg, cov: p.cov, trail: r.trail, t: p.t});
  }
  return out;
}

let autoFit = true;  // a floor without a plan is fitted to the responders once they appear
let flash = null;

function animationFrame(ts) {
  frameTick(ts);
  const phase = flashPhase();  // unacknowledged alarms flash on the map: redraw when the phase turns
  if (phase !== flash && S.mode === "live" && [...S.alarms.values()].some((a) => !a.acked)) S.dirty = true;
  flash = phase;
  if (S.dirty) {
    S.dirty = false;
    const pos = positions();
    if (autoFit && pos.length) { autoFit = false; if (!frame().bounds) fit(); }
    drawResponders(pos);
  }
  requestAnimationFrame(animationFrame);
}

function refreshPanels() {
  renderRoster();
  renderFloorButtons();
  renderSelection();
  const lag = serviceBehind(S.responders.values(), serverNow());
  $("behind").hidden = lag < S.settings.behind_s;
  setText($("behind"), lag >= S.settings.behind_s ? `SERVICE BEHIND ${lag.toFixed(1)} s` : "");
  const rej = Object.entries(S.rejected).filter(([, n]) => n > 0);
  $("rejected").hidden = rej.length === 0;
  setText($("rejected"), rej.length ? "ignored messages: " + rej.map(([k, n]) => `${k} ${n}`).join(", ") : "");
}

function bindKeys() {
  $("other-floors").onchange = (e) => { S.showOtherFloors = e.target.checked; S.dirty = true; };
  document.addEventListener("keydown", (e) => {
    if (modalOpen() || e.target.tagName === "INPUT") return;
    if (e.key === "Escape") setAddMode(false);
    else if (e.key === "f" || e.key === "F") fit();
    else if (e.key === "a" || e.key === "A") fitResponders();
  });
}

async function start() {
  bindModal();
  await login();
  bindKeys();
  bindRoster();
  bindActions(renderRoster);
  bindReview();
  bindPar();
  bindPhones();
  const inc = await getJSON("/api/incident");
  S.incident = inc;
  S.settings = {...S.settings, ...inc.settings};
  S.floors = inc.floors;
  S.checkpoints = inc.checkpoints;
  S.beacons = inc.beacons || [];
  seedRoster(inc.roster);
  $("incident-name").textContent = `${inc.name || inc.id}`;
  document.title = `firetrack · ${inc.name || inc.id}`;
  createMap($("map"), onMapClick);
  buildFloors(inc);
  initResponders();
  setFloor(S.plans[inc.start_floor] ? inc.start_floor : S.floors[0].number);
  fit();
  fillCheckpointList();
  connect();
  setInterval(refreshPanels, PANELS_PERIOD_MS);
  setInterval(evaluateAlarms, ALARM_PERIOD_MS);
  setInterval(() => { $("clock").textContent = new Date().toLocaleTimeString([], {hour12: false}); }, CLOCK_PERIOD_MS);
  requestAnimationFrame(animationFrame);
  S.ready = true;
}

// ------------------------------------------------------------------ for tests and tools
Object.assign(S, {
  enuToScreen, screenToEnu, fit, fitResponders, setFloor, setReviewOffset, perfStats, resetPerf,
  select: (id) => select(id, true),
  centreOn: (x, y) => { centreOn(x, y, false); return enuToScreen(x, y); },
  bearingToScreen: (deg) => bearingToScreen(frame(), deg),
  ellipseAxes, ellipseOutline,
  map: () => map,
  snapshot: () => Object.fromEntries([...S.responders.values()].map(
    (r) => [r.id, {pose: r.pose, status: r.status, trail: r.trail.length, lastRx: r.lastRx}])),
  drawnPositions: () => Object.fromEntries((S.drawn || []).map((q) => {
    const [X, Y] = enuToScreen(q.x, q.y);
    return [q.id, {x: q.x, y: q.y, floor: q.floor, X, Y, t: q.t}];
  })),
  alarmList: () => [...S.alarms.values()].map((a) => ({...a})),
});
window.__firetrack = S;

start().catch((e) => { toast(`The console could not start: ${e.message}`, "error"); console.error(e); });
