/* How hard the page works, for tests and tools (window.__firetrack.perfStats()):
   draw_ms            drawing work per animation frame: painting the responders (map/responders.js,
                      on new data and after the view moved); Leaflet moves the plan on the GPU
   frame_interval_ms  time between animation frames: long ones mean the main thread was blocked
   message_ms         handling one WebSocket message */

const KEEP = 600;  // samples kept per list

const lists = {draw: [], frame: [], message: []};
let work = 0, lastFrame = null;

export function addSample(name, ms) {
  const l = lists[name];
  l.push(ms);
  if (l.length > KEEP) l.shift();
}

/** Drawing work done now; summed per animation frame. */
export function addWork(ms) { work += ms; }

/** Call once per animation frame, first thing. */
export function frameTick(ts) {
  if (lastFrame !== null) addSample("frame", ts - lastFrame);
  lastFrame = ts;
  if (work > 0) { addSample("draw", work); work = 0; }
}

function quantile(l, q) {
  if (!l.length) return null;
  const s = [...l].sort((a, b) => a - b);
  return s[Math.min(s.length - 1, Math.floor(q * s.length))];
}

export function perfStats() {
  const f = (l) => ({n: l.length, p50: quantile(l, 0.5), p95: quantile(l, 0.95), max: l.length ? Math.max(...l) : null});
  return {draw_ms: f(lists.draw), frame_interval_ms: f(lists.frame), message_ms: f(lists.message)};
}

export function resetPerf() { for (const l of Object.values(lists)) l.length = 0; }
