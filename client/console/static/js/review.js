/* Review: scrub back through every responder's smoothed track (GET /api/tracks, the service's
   track queryable). The slider's offset is seconds before the latest sample of all tracks;
   each responder is drawn at that device time, linearly interpolated between its samples, with
   its trail up to there. Fixes are placed in LIVE mode only. */
import {S} from "./state.js";
import {$, ago, toast} from "./ui.js";
import {getJSON} from "./api.js";

function setMode(mode) {
  S.mode = mode;
  $("review-bar").hidden = mode !== "review";
  $("btn-review").classList.toggle("on", mode === "review");
  $("btn-live").classList.toggle("on", mode === "live");
  S.dirty = true;
}

async function enterReview() {
  let data;
  try { data = await getJSON("/api/tracks"); } catch (e) { toast(`Tracks not available: ${e.message}`, "error"); return; }
  const tracks = new Map(Object.entries(data.tracks));
  let span = 0;
  for (const tr of tracks.values()) if (tr.t.length) span = Math.max(span, tr.t[tr.t.length - 1] - tr.t[0]);
  const offset = S.review ? Math.max(S.review.offset, -span) : 0;
  S.review = {tracks, span, offset};
  const sl = $("scrub");
  sl.min = String(-Math.ceil(span)); sl.max = "0"; sl.value = String(offset);
  label();
  setMode("review");
}

function label() {
  const o = S.review ? S.review.offset : 0;
  $("scrub-label").textContent = o === 0 ? "latest sample" : `${ago(-o)} before the latest sample`;
}

/** Show the tracks `offset` seconds (<= 0) before the latest sample. */
export function setReviewOffset(offset) {
  if (!S.review) return;
  S.review.offset = offset;
  $("scrub").value = String(offset);
  label();
  S.dirty = true;
}

/** Where each responder is at the scrubbed time: [{id, x, y, floor, heading, cov: null, trail, t}]. */
export function reviewPositions() {
  const out = [];
  for (const [id, tr] of S.review.tracks) {
    const n = tr.t.length;
    if (!n) continue;
    const te = tr.t[n - 1] + S.review.offset;
    if (te < tr.t[0]) continue;  // not yet on the track at that time
    let lo = 0, hi = n - 1;  // the last sample at or before te
    while (lo < hi) { const mid = (lo + hi + 1) >> 1; if (tr.t[mid] <= te) lo = mid; else hi = mid - 1; }
    let x = tr.x[lo], y = tr.y[lo];
    if (lo < n - 1 && tr.t[lo + 1] > tr.t[lo]) {
      const w = (te - tr.t[lo]) / (tr.t[lo + 1] - tr.t[lo]);
      x += w * (tr.x[lo + 1] - tr.x[lo]); y += w * (tr.y[lo + 1] - tr.y[lo]);
    }
    const trail = [];
    for (let i = Math.max(0, lo - S.settings.trail_points); i <= lo; i++) trail.push([tr.t[i], tr.x[i], tr.y[i], tr.floor[i]]);
    trail.push([te, x, y, tr.floor[lo]]);
    out.push({id, x, y, floor: tr.floor[lo], heading: tr.heading_deg[lo], cov: null, trail, t: te});
  }
  return out;
}

export function bindReview() {
  $("btn-live").onclick = () => setMode("live");
  $("btn-review").onclick = enterReview;
  $("btn-review-reload").onclick = enterReview;
  $("scrub").oninput = (e) => setReviewOffset(parseFloat(e.target.value));
}
