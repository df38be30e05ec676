/* global L */
/* Floors: each is a Leaflet layer group of its base (the plan image as an image overlay, or a
   grid in metres) and its named checkpoints; showing a floor swaps groups. Also the floor
   buttons (with how many responders are on each) and the notice about a missing plan. */
import {S, frame} from "../state.js";
import {$, setText, toast} from "../ui.js";
import {metreGrid} from "./grid.js";
import {floorFrame} from "./projection.js";
import {map, pointNorth} from "./view.js";

const floors = new Map();  // floor number -> {group, checkpoints}

/** The frames of the incident's plans (GET /api/incident), and a layer group per floor. */
export function buildFloors(incident) {
  for (const [n, p] of Object.entries(incident.plans)) S.plans[Number(n)] = floorFrame(p);
  for (const f of S.floors) {
    const fr = S.plans[f.number], checkpoints = L.layerGroup(), group = L.layerGroup([checkpoints]);
    if (fr.url) {
      const plan = L.imageOverlay(fr.url, fr.bounds, {className: "plan"});
      plan.on("load", () => { S.planLoaded = true; });
      plan.on("error", () => {  // the grid instead, in the same frame
        toast(`Floor plan ${fr.url} could not be loaded; showing a grid`, "error");
        group.removeLayer(plan);
        group.addLayer(metreGrid(fr));
      });
      group.addLayer(plan);
    } else {
      group.addLayer(metreGrid(fr));
    }
    floors.set(f.number, {group, checkpoints});
  }
  drawCheckpoints();
}

/** (Re)draw every floor's checkpoints (a yellow diamond and its name) and BLE beacons (a blue
    dot and its name, or id); clicks go through to the map. */
export function drawCheckpoints() {
  for (const [n, {checkpoints}] of floors) {
    checkpoints.clearLayers();
    for (const b of S.beacons) {
      if (b.floor !== n) continue;
      L.marker(S.plans[n].toLatLng(b.x, b.y), {
        interactive: false, keyboard: false,
        icon: L.divIcon({className: "beacon", iconSize: null, html: "<div></div>"}),
      }).bindTooltip(b.name || b.id, {permanent: true, direction: "right", className: "checkpoint-label beacon-label"})
        .addTo(checkpoints);
    }
    for (const c of S.checkpoints) {
      if (c.floor !== n) continue;
      L.marker(S.plans[n].toLatLng(c.x, c.y), {
        interactive: false, keyboard: false,
        icon: L.divIcon({className: "checkpoint", iconSize: null, html: "<div></div>"}),
      }).bindTooltip(c.name, {permanent: true, direction: "right", className: "checkpoint-label"})
        .addTo(checkpoints);
    }
  }
}

/** Show floor n, keeping the place at the centre of the view and the zoom. */
export function setFloor(n) {
  if (!S.plans[n]) return;
  const before = floors.get(S.floor), centre = before ? frame().toEnu(map.getCenter()) : null;
  if (before) map.removeLayer(before.group);
  S.floor = n;
  const fr = frame(), f = S.floors.find((q) => q.number === n);
  map.addLayer(floors.get(n).group);
  if (centre) map.setView(fr.toLatLng(...centre), map.getZoom(), {animate: false});
  pointNorth();
  $("map-notice").textContent = fr.url
    ? (fr.fallback ? `Floor ${n} (${f.name}) has no plan of its own: showing the plan of floor ${fr.plan_floor}.` : "")
    : `Floor ${n} (${f.name}): ${fr.problem}. Showing a grid in metres.`;
  S.dirty = true;
  renderFloorButtons();
}

export function renderFloorButtons() {
  const box = $("floor-buttons"), counts = {};
  for (const r of S.responders.values()) if (r.pose) counts[r.pose.floor] = (counts[r.pose.floor] || 0) + 1;
  for (const f of S.floors) {
    let b = box.querySelector(`[data-floor="${f.number}"]`);
    if (!b) {
      b = document.createElement("button");
      b.dataset.floor = f.number;
      b.title = f.name;
      b.innerHTML = '<span class="name"></span><span class="n"></span>';
      b.addEventListener("click", () => setFloor(f.number));
      box.appendChild(b);
    }
    b.classList.toggle("on", f.number === S.floor);
    setText(b.querySelector(".name"), `${f.number}`);
    setText(b.querySelector(".n"), `· ${counts[f.number] || 0}`);
  }
}
