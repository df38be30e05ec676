/* global L */
/* The responders on the map: one canvas, a Leaflet renderer (L.Renderer keeps it placed under
   the view, padded, and scales it during zoom animations; it is repainted at every moveend and
   whenever drawResponders is called). Painted in this order:
     responders on other floors   small grey dots (unless hidden)
     trails                       recent points on the shown floor, in the responder's colour
     ellipses                     the 95 % region of each position's covariance (projection.js);
                                  dashed and untinted when wider than VAGUE_SEMI_AXIS_M
     marks                        a dot with the heading arrow (red in alarm), a flashing red
                                  ring while an alarm is unacknowledged, a yellow ring if selected
     names                        above every mark
   One canvas, not a Leaflet layer per responder: with 200 responders updated twice a second
   (tests/test_console_browser.py) HTML markers took about 16 ms per update and a Leaflet canvas
   layer each 10-16 ms (median), against about 4 ms for this one canvas.

   drawResponders(positions) paints [{id, x, y, floor, heading, cov, trail, t}] (live poses or
   review samples); responderAt(point) is the one whose mark is under a container point. */
import {S, alarmSets, frame} from "../state.js";
import {addWork} from "../perf.js";
import {ELLIPSE_SEGMENTS, bearingToScreen, ellipseAxes, ellipseOutline} from "./projection.js";
import {enuToScreen, map} from "./view.js";

const PALETTE = ["#0047ab", "#007a33", "#6a1b9a", "#a34700", "#00707a", "#4e342e", "#1a237e", "#33691e",
                 "#ad1457", "#37474f"];
const ALARM = "#e00000", SELECT = "#ffd400", OTHER = "rgba(110,110,110,0.75)";
const MARK_R = 9;               // px, the dot's radius
const OTHER_R = 5;              // px, a responder on another floor
const HIT_PX = 24;              // a click this close to a dot selects it
const ARROW_PX = 24;            // heading arrow length beyond the centre
const NAME_FONT = "bold 15px system-ui, sans-serif";
const VAGUE_SEMI_AXIS_M = 15;   // an ellipse this wide means "not placed yet": outline only, no tint
const MAX_SEMI_AXIS_M = 1e4;    // larger (or not finite): not drawn at all
const FLASH_MS = 500;           // unacknowledged alarm rings flash at this half-period

/** A responder's colour, fixed by its id. */
export function colorOf(id) {
  let h = 0;
  for (let i = 0; i < id.length; i++) h = (h * 31 + id.charCodeAt(i)) >>> 0;
  return PALETTE[h % PALETTE.length];
}

/** True in the "on" half of the flash period; the page repaints when it turns. */
export const flashPhase = () => Math.floor(Date.now() / FLASH_MS) % 2 === 0;

const ResponderCanvas = L.Renderer.extend({
  _initContainer() {
    this._container = document.createElement("canvas");
    this._ctx = this._container.getContext("2d");
  },
  _destroyContainer() { L.DomUtil.remove(this._container); },
  _update() {  // the view moved or resized: cover it again and repaint
    if (this._map._animatingZoom && this._bounds) return;
    L.Renderer.prototype._update.call(this);
    const b = this._bounds, size = b.getSize(), dpr = window.devicePixelRatio || 1, c = this._container;
    L.DomUtil.setPosition(c, b.min);
    c.width = Math.round(dpr * size.x); c.height = Math.round(dpr * size.y);
    c.style.width = `${size.x}px`; c.style.height = `${size.y}px`;
    this._ctx.setTransform(dpr, 0, 0, dpr, -dpr * b.min.x, -dpr * b.min.y);  // draw in layer points
    paint(this);
  },
});

let canvas = null;
let drawn = [];  // what was painted last

export function initResponders() {
  map.createPane("responders").style.zIndex = 450;  // above the plan and grid (400), under markers (600)
  canvas = new ResponderCanvas({pane: "responders", padding: 0.1}).addTo(map);
}

/** ENU -> layer point as the affine map it is, [ox, oy, ax, ay, bx, by]: X = ox + ax x + bx y,
    Y = oy + ay x + by y (three projections per paint, not one per point). */
function layerMap() {
  const fr = frame(), origin = map.getPixelOrigin();
  const P = (x, y) => map.project(fr.toLatLng(x, y)).subtract(origin);
  const o = P(0, 0), ex = P(1, 0).subtract(o), ey = P(0, 1).subtract(o);
  return [o.x, o.y, ex.x, ex.y, ey.x, ey.y];
}

export function drawResponders(positions) {
  drawn = positions;
  S.drawn = positions;
  if (canvas) paint(canvas);
}

const outline = new Float64Array(2 * ELLIPSE_SEGMENTS);  // one ellipse at a time, no garbage

function paint(renderer) {
  const t0 = performance.now();
  const ctx = renderer._ctx, b = renderer._bounds, size = b.getSize();
  ctx.clearRect(b.min.x, b.min.y, size.x, size.y);
  const fr = frame();
  if (!fr) return;
  const [ox, oy, ax, ay, bx, by] = layerMap(), live = S.mode === "live", al = alarmSets(), flashOn = flashPhase();
  const here = [], other = [];
  for (const q of drawn) (q.floor === S.floor ? here : other).push({q, X: ox + ax * q.x + bx * q.y, Y: oy + ay * q.x + by * q.y});

  if (S.showOtherFloors && other.length) {
    ctx.beginPath();
    for (const {X, Y} of other) { ctx.moveTo(X + OTHER_R, Y); ctx.arc(X, Y, OTHER_R, 0, 2 * Math.PI); }
    ctx.fillStyle = OTHER; ctx.fill(); ctx.lineWidth = 1.5; ctx.strokeStyle = "#fff"; ctx.stroke();
  }
  ctx.lineJoin = "round";
  ctx.lineWidth = 2.5; ctx.globalAlpha = 0.6;
  for (const {q} of here) {
    if (!q.trail || q.trail.length < 2) continue;
    ctx.beginPath();
    let pen = false;
    for (const [, x, y, floor] of q.trail) {
      if (floor !== S.floor) { pen = false; continue; }
      const X = ox + ax * x + bx * y, Y = oy + ay * x + by * y;
      if (pen) ctx.lineTo(X, Y); else { ctx.moveTo(X, Y); pen = true; }
    }
    ctx.strokeStyle = colorOf(q.id); ctx.stroke();
  }
  ctx.lineWidth = 1.5;
  for (const {q} of here) {
    const r1 = q.cov ? ellipseAxes(q.cov)[0] : NaN;
    if (!(r1 < MAX_SEMI_AXIS_M)) continue;
    const e = ellipseOutline(q.x, q.y, q.cov, outline);
    ctx.beginPath();
    for (let i = 0; i < e.length; i += 2) ctx.lineTo(ox + ax * e[i] + bx * e[i + 1], oy + ay * e[i] + by * e[i + 1]);
    ctx.closePath();
    const vague = r1 > VAGUE_SEMI_AXIS_M;
    ctx.fillStyle = ctx.strokeStyle = colorOf(q.id);
    if (!vague) { ctx.globalAlpha = 0.13; ctx.fill(); }
    ctx.globalAlpha = 0.8;
    if (vague) ctx.setLineDash([8, 6]);
    ctx.stroke();
    if (vague) ctx.setLineDash([]);
  }
  ctx.globalAlpha = 1;
  for (const {q, X, Y} of here) paintMark(ctx, X, Y, q, live && al.active.has(q.id), live && al.unacked.has(q.id) && flashOn, fr);
  ctx.font = NAME_FONT; ctx.lineWidth = 4;
  for (const {q, X, Y} of here) {
    const x = X + MARK_R + 4, y = Y - MARK_R - 2;
    ctx.strokeStyle = "#fff"; ctx.strokeText(q.id, x, y);
    ctx.fillStyle = live && al.active.has(q.id) ? "#c00000" : "#000"; ctx.fillText(q.id, x, y);
  }
  addWork(performance.now() - t0);
}

function paintMark(ctx, X, Y, q, alarmed, flash, fr) {
  const col = alarmed ? ALARM : colorOf(q.id);
  const ring = (r, width, color) => {
    ctx.beginPath(); ctx.arc(X, Y, r, 0, 2 * Math.PI); ctx.lineWidth = width; ctx.strokeStyle = color; ctx.stroke();
  };
  if (flash) ring(MARK_R + 11, 6, ALARM);
  if (q.id === S.selected) { ring(MARK_R + 6, 7, "#000"); ring(MARK_R + 6, 4, SELECT); }
  if (q.heading !== null && q.heading !== undefined) {
    const [dx, dy] = bearingToScreen(fr, q.heading), tx = X + dx * ARROW_PX, ty = Y + dy * ARROW_PX;
    ctx.beginPath(); ctx.moveTo(X, Y); ctx.lineTo(tx, ty); ctx.lineWidth = 3; ctx.strokeStyle = col; ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(tx + dx * 6, ty + dy * 6);
    ctx.lineTo(tx - dx * 4 - dy * 6, ty - dy * 4 + dx * 6);
    ctx.lineTo(tx - dx * 4 + dy * 6, ty - dy * 4 - dx * 6);
    ctx.closePath(); ctx.fillStyle = col; ctx.fill();
  }
  ctx.beginPath(); ctx.arc(X, Y, MARK_R, 0, 2 * Math.PI);
  ctx.fillStyle = col; ctx.fill(); ctx.lineWidth = 2.5; ctx.strokeStyle = "#fff"; ctx.stroke();
}

/** The id of the responder on the shown floor whose mark is nearest the container point (within HIT_PX), or null. */
export function responderAt(point) {
  let best = null, bestD = HIT_PX;
  for (const q of drawn) {
    if (q.floor !== S.floor) continue;
    const [X, Y] = enuToScreen(q.x, q.y), d = Math.hypot(X - point.x, Y - point.y);
    if (d < bestD) { best = q.id; bestD = d; }
  }
  return best;
}
