/* Frames of the console map. Pure maths: no DOM, no Leaflet.

   ENU (x East, y North, m) is the navigation frame. Each floor shows a plan image with an affine
   map  [x, y] = A [u, v] + b  (u right, v down, served-image pixels; client/console/plans.py), or,
   without a plan, a grid whose map is A = diag(1/20, -1/20), b = 0.

   The Leaflet map (L.CRS.Simple) is drawn in "map units": plan pixels scaled by
   k = sqrt|det A| (metres per pixel), lat = -k v, lng = k u. The image stays upright and a map
   unit is a metre whenever A is a rotation and a scale (a similarity), so Leaflet's scale bar
   and the zoom level mean the same on every floor. On a grid floor lat = y and lng = x.

   Uncertainty: a covariance C (ENU, m^2) is drawn as its 95 % region,
   (p - m)^T C^-1 (p - m) = k^2 with k = sqrt(chi2_2(0.95)) = sqrt(-2 ln 0.05) = 2.4477
   (a 2-D Gaussian's Mahalanobis radius is Rayleigh distributed). */

export const ELLIPSE_K = 2.4477;
export const ELLIPSE_SEGMENTS = 48;

/** The map frame of one floor, from the server's plan JSON ({matrix, url, width, height, ...}). */
export function floorFrame(plan) {
  const m = plan.matrix;
  const A = [[m[0][0], m[0][1]], [m[1][0], m[1][1]]];
  const b = [m[0][2], m[1][2]];
  const det = A[0][0] * A[1][1] - A[0][1] * A[1][0];
  const Ai = [[A[1][1] / det, -A[0][1] / det], [-A[1][0] / det, A[0][0] / det]];
  const k = Math.sqrt(Math.abs(det));
  return {
    ...plan, A, b, Ai, k,
    /** ENU (m) -> [lat, lng] in map units. */
    toLatLng(x, y) {
      const dx = x - b[0], dy = y - b[1];
      return [-k * (Ai[1][0] * dx + Ai[1][1] * dy), k * (Ai[0][0] * dx + Ai[0][1] * dy)];
    },
    /** {lat, lng} in map units -> ENU [x, y] (m). */
    toEnu(ll) {
      const u = ll.lng / k, v = -ll.lat / k;
      return [A[0][0] * u + A[0][1] * v + b[0], A[1][0] * u + A[1][1] * v + b[1]];
    },
    /** The plan image's corners [[lat, lng] south-west, north-east], or null on a grid floor. */
    bounds: plan.width ? [[-k * plan.height, 0], [0, k * plan.width]] : null,
  };
}

/** A compass bearing (deg, clockwise from North) as a unit vector on screen (x right, y down). */
export function bearingToScreen(frame, deg) {
  const r = deg * Math.PI / 180, Ai = frame.Ai;
  const ex = Math.sin(r), ey = Math.cos(r);  // the bearing's ENU unit vector
  const u = Ai[0][0] * ex + Ai[0][1] * ey, v = Ai[1][0] * ex + Ai[1][1] * ey;
  const n = Math.hypot(u, v) || 1;
  return [u / n, v / n];
}

/** ENU covariance [xx, xy, yy] (m^2) -> [r1, r2, angle]: semi-axes (m) of the 95 % ellipse and
    the major axis's direction (rad, counter-clockwise from East). Closed-form 2x2 eigenvalues. */
export function ellipseAxes(c) {
  const [a, b, d] = c;
  const mid = (a + d) / 2, rad = Math.sqrt(((a - d) / 2) ** 2 + b * b);
  const l1 = Math.max(mid + rad, 0), l2 = Math.max(mid - rad, 0);
  return [ELLIPSE_K * Math.sqrt(l1), ELLIPSE_K * Math.sqrt(l2), 0.5 * Math.atan2(2 * b, a - d)];
}

/** The 95 % ellipse of covariance c around ENU (x, y): ELLIPSE_SEGMENTS points, flat
    [x0, y0, x1, y1, ...] (m), written into `out` (the map reuses one array for every responder). */
export function ellipseOutline(x, y, c, out = new Float64Array(2 * ELLIPSE_SEGMENTS)) {
  const [r1, r2, th] = ellipseAxes(c);
  const ct = Math.cos(th), st = Math.sin(th);
  for (let i = 0; i < ELLIPSE_SEGMENTS; i++) {
    const phi = 2 * Math.PI * i / ELLIPSE_SEGMENTS;
    const p = r1 * Math.cos(phi), q = r2 * Math.sin(phi);
    out[2 * i] = x + p * ct - q * st;
    out[2 * i + 1] = y + p * st + q * ct;
  }
  return out;
}
