/* global L */
/* A grid in metres, for floors without a plan (or whose plan image failed): a Leaflet
   GridLayer whose canvas tiles draw the ENU lines x = i s and y = j s through the floor's
   frame (so the grid is right on a rotated plan frame too), labelled at each tile's top and
   left edges. The spacing s is the 1-2-5 step nearest above GRID_PX screen pixels. */

const TILE_PX = 512;
const GRID_PX = 60;  // about this many screen pixels between lines

/** The smallest of 1, 2, 5 x 10^n that is at least `metres`. */
export function niceStep(metres) {
  const e = Math.pow(10, Math.floor(Math.log10(metres)));
  for (const m of [1, 2, 5, 10]) if (m * e >= metres) return m * e;
  return 10 * e;
}

const MetreGrid = L.GridLayer.extend({
  options: {tileSize: TILE_PX, className: "metre-grid"},

  initialize(frame, options) { this._frame = frame; L.setOptions(this, options); },

  createTile(coords) {
    const tile = document.createElement("canvas");
    tile.width = tile.height = TILE_PX;
    const ctx = tile.getContext("2d"), fr = this._frame, z = Math.pow(2, coords.z);
    const x0 = coords.x * TILE_PX, y0 = coords.y * TILE_PX;
    const toPx = (x, y) => { const [lat, lng] = fr.toLatLng(x, y); return [lng * z - x0, -lat * z - y0]; };
    const toEnu = (px, py) => fr.toEnu({lat: -(py + y0) / z, lng: (px + x0) / z});
    const corners = [toEnu(0, 0), toEnu(TILE_PX, 0), toEnu(0, TILE_PX), toEnu(TILE_PX, TILE_PX)];
    const xs = corners.map((c) => c[0]), ys = corners.map((c) => c[1]);
    const [xmin, xmax, ymin, ymax] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
    const step = niceStep(GRID_PX / z);  // map units are metres: z screen px per metre
    ctx.fillStyle = "#f4f4f4";
    ctx.fillRect(0, 0, TILE_PX, TILE_PX);
    ctx.font = "12px system-ui, sans-serif";
    ctx.fillStyle = "#444";
    ctx.lineWidth = 1;
    const line = (a, b, origin) => {
      ctx.strokeStyle = origin ? "#555" : "#c8c8c8";
      ctx.beginPath(); ctx.moveTo(...a); ctx.lineTo(...b); ctx.stroke();
    };
    for (let x = Math.ceil(xmin / step) * step; x <= xmax; x += step) {
      const a = toPx(x, ymax), b = toPx(x, ymin);
      line(a, b, Math.abs(x) < 1e-9);
      ctx.fillText(`${+x.toFixed(1)} m`, a[0] + 3, 14);
    }
    for (let y = Math.ceil(ymin / step) * step; y <= ymax; y += step) {
      const a = toPx(xmin, y), b = toPx(xmax, y);
      line(a, b, Math.abs(y) < 1e-9);
      ctx.fillText(`${+y.toFixed(1)} m`, 4, a[1] - 3);
    }
    return tile;
  },
});

export const metreGrid = (frame) => new MetreGrid(frame);
