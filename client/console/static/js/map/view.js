/* global L */
/* The Leaflet map (vendor/leaflet, L.CRS.Simple in the floor's map units, see projection.js):
   pan and zoom, the scale bar, the north arrow, fitting the view, and ENU <-> screen for the
   rest of the page. */
import {S, frame} from "../state.js";
import {$} from "../ui.js";
import {bearingToScreen} from "./projection.js";

const MIN_ZOOM = -5;              // 2^zoom screen px per metre: 1/32 ...
const MAX_ZOOM = 8;               // ... 256
const ZOOM_STEP = Math.log2(1.5); // one button press or key: 1.5 times closer
const WHEEL_PX_PER_ZOOM = 120;    // wheel travel (px) per zoom level
const FIT_PADDING_PX = 20;        // room around a fitted plan or crowd
const FIT_MARGIN_M = 6;           // metres around the outermost responders when fitting them
const EMPTY_HALF_SPAN_M = 25;     // a grid floor with nothing on it shows this far around the origin
const SCALE_MAX_PX = 160;

/** The Leaflet map, once createMap ran. */
export let map = null;
let needle = null;

const NorthArrow = L.Control.extend({
  onAdd() {
    const div = L.DomUtil.create("div", "north");
    div.title = "north";
    div.innerHTML = '<svg viewBox="-30 -30 60 60" aria-hidden="true"><g class="needle">' +
                    '<path class="shaft" d="M0 22V-6"/><path class="head" d="M0-15L-7-2H7Z"/>' +
                    '<text y="-18" text-anchor="middle">N</text></g></svg>';
    needle = div.querySelector(".needle");
    return div;
  },
});

/** The map in element `el`; onClick(x, y, point) gets clicks on the map: ENU (m) and container point (px). */
export function createMap(el, onClick) {
  map = L.map(el, {
    crs: L.CRS.Simple, zoomSnap: 0, zoomDelta: ZOOM_STEP, wheelPxPerZoomLevel: WHEEL_PX_PER_ZOOM,
    minZoom: MIN_ZOOM, maxZoom: MAX_ZOOM, zoomControl: false, attributionControl: false,
    doubleClickZoom: false,  // a click is an action (a fix): two of them must not also zoom
  });
  map.setView([0, 0], 0);
  // the alarm list and the review bar change the map's box, not the window's: follow the element,
  // keeping every point where it was on the screen (a bar that appears above the map as the
  // officer clicks must not move the spot under the pointer; Leaflet's own resize keeps the
  // centre, which moves everything by half the bar's height)
  let box = el.getBoundingClientRect();
  new ResizeObserver(() => {
    const now = el.getBoundingClientRect(), dx = now.left - box.left, dy = now.top - box.top;
    box = now;
    map.invalidateSize({pan: false});  // the view's top-left corner stays on the element's
    if (dx || dy) map.panBy([dx, dy], {animate: false});  // and goes back to where it was on the screen
  }).observe(el);
  L.control.scale({imperial: false, maxWidth: SCALE_MAX_PX, position: "bottomleft"}).addTo(map);
  new NorthArrow({position: "topright"}).addTo(map);
  map.on("click", (e) => { const [x, y] = frame().toEnu(e.latlng); onClick(x, y, e.containerPoint); });
  $("zoom-in").onclick = () => map.zoomIn(ZOOM_STEP);
  $("zoom-out").onclick = () => map.zoomOut(ZOOM_STEP);
  $("zoom-fit").onclick = () => fit();
  $("zoom-all").onclick = () => fitResponders();
  return map;
}

/** Turn the north arrow to the shown floor's frame. */
export function pointNorth() {
  const [nx, ny] = bearingToScreen(frame(), 0);
  needle.setAttribute("transform", `rotate(${Math.atan2(nx, -ny) * 180 / Math.PI})`);
}

/** ENU (m) -> container pixels, unrounded (Leaflet's latLngToContainerPoint rounds). */
export function enuToScreen(x, y) {
  const p = map.layerPointToContainerPoint(map.project(frame().toLatLng(x, y)).subtract(map.getPixelOrigin()));
  return [p.x, p.y];
}

export const screenToEnu = (X, Y) => frame().toEnu(map.containerPointToLatLng([X, Y]));

/** Centre the view on ENU (x, y) at the same zoom. */
export function centreOn(x, y, animate = true) {
  map.setView(frame().toLatLng(x, y), map.getZoom(), {animate});
}

/** Show ENU points with FIT_MARGIN_M around them. */
function showPoints(pts) {
  const f = frame(), ll = pts.map(([x, y]) => f.toLatLng(x, y));
  const lat = ll.map((p) => p[0]), lng = ll.map((p) => p[1]), m = FIT_MARGIN_M;
  map.fitBounds([[Math.min(...lat) - m, Math.min(...lng) - m], [Math.max(...lat) + m, Math.max(...lng) + m]],
                {padding: [FIT_PADDING_PX, FIT_PADDING_PX]});
}

const posed = () => [...S.responders.values()].filter((r) => r.pose);

/** Fit the plan; without one, everything known on this floor. */
export function fit() {
  const f = frame();
  if (!f) return;
  if (f.bounds) { map.fitBounds(f.bounds, {padding: [FIT_PADDING_PX, FIT_PADDING_PX]}); return; }
  const pts = posed().map((r) => [r.pose.x, r.pose.y]);
  for (const c of S.checkpoints) if (c.floor === S.floor) pts.push([c.x, c.y]);
  if (!pts.length) pts.push([-EMPTY_HALF_SPAN_M, -EMPTY_HALF_SPAN_M], [EMPTY_HALF_SPAN_M, EMPTY_HALF_SPAN_M]);
  showPoints(pts);
}

/** Zoom to every responder on the shown floor (all responders when none is on it). */
export function fitResponders() {
  let rs = posed().filter((r) => r.pose.floor === S.floor);
  if (!rs.length) rs = posed();
  if (rs.length) showPoints(rs.map((r) => [r.pose.x, r.pose.y])); else fit();
}
