/* What the page knows: one store S that every module reads and the live data writes.

   Modules change S and set S.dirty (the map redraws the responders on the next animation
   frame); the roster and the alarms re-render on their own timers. window.__firetrack is S,
   with the functions main.js adds for tests and tools. */

export const S = {
  incident: null,
  floors: [],
  plans: {},              // floor -> frame (map/projection.js floorFrame) with url, width, height, fallback, problem
  floor: 0,
  checkpoints: [],
  beacons: [],            // BLE beacons of the incident config: {id, name, x, y, floor, sigma_m}
  responders: new Map(),  // id -> {id, member, pose, status, trail: [[t, x, y, floor]], lastRx}
  roster: new Map(),      // id -> {id, name, team, role}: who is expected (incident config)
  alarms: new Map(),      // "id|kind" -> {key, responder, kind, active, acked, count, raisedAt, clearedAt}
  selected: null,
  mode: "live",           // "live" or "review"
  review: null,           // {tracks: Map, span, offset}
  showOtherFloors: true,
  clockOffset: 0,         // server clock - page clock (s), from each message's "now"
  connected: false,
  rejected: {},           // the service's counts of ignored messages, by reason
  flags: {},              // responder -> the service's audit of its latest implausible fix
  session: null,          // who is logged in: {auth: "open"|"required", user, role}
  settings: {lost_contact_s: 10, trail_points: 120, behind_s: 1.0},  // behind_s: the "SERVICE BEHIND" banner from this lag
  dirty: true,            // the responders layer must be redrawn
  messages: 0,
  ready: false,
};

/** The server's clock now (s since the epoch). */
export const serverNow = () => Date.now() / 1000 + S.clockOffset;

/** The map frame of the floor shown. */
export const frame = () => S.plans[S.floor];

export function responder(id) {
  let r = S.responders.get(id);
  if (!r) {
    r = {id, member: S.roster.get(id) || null, pose: null, status: null, trail: [], lastRx: 0};
    S.responders.set(id, r);
  }
  return r;
}

/** The incident's roster: every expected responder has a row before their wearable is heard. */
export function seedRoster(members) {
  for (const m of members || []) {
    S.roster.set(m.id, m);
    responder(m.id).member = m;
  }
}

/** Seconds since the wearable's last frame reached the service (the service's clock), or NaN. */
export const heardAgo = (r, now) => (r.status ? now - r.status.last_heard : NaN);

/** A Pose from the service: the latest position, and a trail point when it moved. */
export function applyPose(p, trail = true) {
  const r = responder(p.responder);
  r.pose = p;
  r.lastRx = Math.max(r.lastRx, p.received_at);
  if (!trail) return;
  const last = r.trail[r.trail.length - 1];
  if (!last || last[0] !== p.t || last[1] !== p.x || last[2] !== p.y) {
    r.trail.push([p.t, p.x, p.y, p.floor]);
    if (r.trail.length > S.settings.trail_points) r.trail.splice(0, r.trail.length - S.settings.trail_points);
  }
}

export function applyStatus(s) {
  const r = responder(s.responder);
  r.status = s;
  r.lastRx = Math.max(r.lastRx, s.received_at);
}

/** Responders with an active alarm, and with one not yet acknowledged. */
export function alarmSets() {
  const active = new Set(), unacked = new Set();
  for (const a of S.alarms.values()) {
    if (a.active) active.add(a.responder);
    if (!a.acked) unacked.add(a.responder);
  }
  return {active, unacked};
}

/** How far behind the service is (s): the median of the lags (Status.lag_s) of the responders
    whose Status came in the last 5 s. One late wearable does not move it; a service that cannot
    keep up moves everyone's (service/core/lag.py). */
export function serviceBehind(responders, now) {
  const lags = [];
  for (const r of responders) {
    if (r.status && r.status.lag_s != null && now - r.status.received_at < 5) lags.push(r.status.lag_s);
  }
  if (!lags.length) return 0;
  lags.sort((a, b) => a - b);
  const m = lags.length >> 1;
  return lags.length % 2 ? lags[m] : 0.5 * (lags[m - 1] + lags[m]);
}
