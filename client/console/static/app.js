/* firetrack console page. Plain JavaScript, no libraries, no build step, works offline.

   Data: GET /api/incident once (floors, checkpoints, plans with their pixel -> ENU maps),
   then a WebSocket /ws: a "snapshot", then batched "update"s (latest pose and status of the
   responders that changed), "checkpoints" and "fix" notices.

   Frames. ENU (x East, y North, m) is the navigation frame. Each floor shows a plan image
   with an affine map  [x, y] = A [u, v] + b  (u right, v down, served-image pixels), or,
   without a plan, a grid in metres with A = diag(1/20, -1/20). The page draws in "map
   units" (plan pixels): ENU -> map with A^-1, map -> screen with the view's pan and zoom.
   A covariance C (ENU, m^2) becomes A^-1 C A^-T in map units; its ellipse is drawn at
   ELLIPSE_K sigma, k = sqrt(chi2_2(0.95)) = 2.448: the 95 % region of a 2-D Gaussian.

   Drawing: two stacked canvases. The background (plan, grid, checkpoints, scale) is
   redrawn only when the view, the floor or the checkpoints change; the foreground
   (markers, ellipses, trails) on the next animation frame after new data. Draw times and
   frame intervals are measured (window.__firetrack.perfStats()).

   Alarms: man_down, lost_contact, rejected_frames, disconnected from the service's Status;
   lost_contact also when the console has heard nothing of a responder for lost_contact_s.
   An alarm flashes until acknowledged; acknowledged it stays listed while it lasts; when it
   ends after acknowledgement it leaves the list; a new occurrence raises it again. */
"use strict";

(() => {
  const ELLIPSE_K = 2.4477;
  const MARKER_R = 9;
  const ELLIPSE_FILL_MAX_PX = 250;
  const ARROW_LEN = 24;
  const HIT_PX = 24;
  const ROSTER_PERIOD_MS = 500;
  const ALARM_PERIOD_MS = 500;
  const PERF_KEEP = 600;
  const PALETTE = ["#0047ab", "#007a33", "#6a1b9a", "#a34700", "#00707a", "#4e342e", "#1a237e", "#33691e",
                   "#ad1457", "#37474f"];
  const ALARM_LABELS = {man_down: "MAN DOWN", lost_contact: "LOST CONTACT", rejected_frames: "BAD DATA",
                        disconnected: "WEARABLE OFF"};
  const MOTION_LABELS = {walking: "walking", still: "still", no_motion: "NO MOTION"};

  const $ = (id) => document.getElementById(id);
  const bg = $("bg"), fg = $("fg");
  const bgx = bg.getContext("2d"), fgx = fg.getContext("2d", {alpha: true});

  const S = {
    incident: null,
    floors: [],
    plans: {},              // floor -> {A, b, Ai, img, width, height, url, fallback, plan_floor, problem}
    floor: 0,
    checkpoints: [],
    responders: new Map(),  // id -> {id, pose, status, trail: [[t,x,y,floor]], lastRx, color}
    alarms: new Map(),      // "id|kind" -> {key, responder, kind, active, acked, count, raisedAt, clearedAt}
    selected: null,
    addCheckpoint: false,
    showOtherFloors: true,
    mode: "live",
    review: null,           // {tracks: Map, span, offset}
    view: {cx: 0, cy: 0, scale: 1, w: 1, h: 1, fitted: false},
    clockOffset: 0,         // server clock - page clock (s)
    connected: false,
    rejected: {},
    settings: {lost_contact_s: 10, trail_points: 120},
    sort: {key: "id", dir: 1},
    perf: {draw: [], frame: [], message: [], lastRaf: null},
    dirtyFg: true,
    dirtyBg: true,
    messages: 0,
  };
  window.__firetrack = S;

  // ------------------------------------------------------------------ frames
  const serverNow = () => Date.now() / 1000 + S.clockOffset;

  function makePlan(p) {
    const m = p.matrix;
    const A = [[m[0][0], m[0][1]], [m[1][0], m[1][1]]];
    const det = A[0][0] * A[1][1] - A[0][1] * A[1][0];
    const Ai = [[A[1][1] / det, -A[0][1] / det], [-A[1][0] / det, A[0][0] / det]];
    return {...p, A, b: [m[0][2], m[1][2]], Ai, img: null};
  }
  const plan = () => S.plans[S.floor];

  function enuToMap(x, y, p = plan()) {
    const dx = x - p.b[0], dy = y - p.b[1];
    return [p.Ai[0][0] * dx + p.Ai[0][1] * dy, p.Ai[1][0] * dx + p.Ai[1][1] * dy];
  }
  function mapToEnu(u, v, p = plan()) {
    return [p.A[0][0] * u + p.A[0][1] * v + p.b[0], p.A[1][0] * u + p.A[1][1] * v + p.b[1]];
  }
  function mapToScreen(u, v) {
    const V = S.view;
    return [(u - V.cx) * V.scale + V.w / 2, (v - V.cy) * V.scale + V.h / 2];
  }
  function screenToMap(X, Y) {
    const V = S.view;
    return [(X - V.w / 2) / V.scale + V.cx, (Y - V.h / 2) / V.scale + V.cy];
  }
  function enuToScreen(x, y) { const [u, v] = enuToMap(x, y); return mapToScreen(u, v); }
  function screenToEnu(X, Y) { const [u, v] = screenToMap(X, Y); return mapToEnu(u, v); }
  /** A compass bearing (deg, CW from North) as a unit vector on screen (y down). */
  function bearingToScreen(deg) {
    const r = deg * Math.PI / 180, p = plan();
    const ex = Math.sin(r), ey = Math.cos(r);
    const u = p.Ai[0][0] * ex + p.Ai[0][1] * ey, v = p.Ai[1][0] * ex + p.Ai[1][1] * ey;
    const n = Math.hypot(u, v) || 1;
    return [u / n, v / n];
  }
  /** ENU covariance [xx, xy, yy] -> screen ellipse [r1, r2, angle] at ELLIPSE_K sigma. */
  function covToEllipse(c) {
    const Ai = plan().Ai, s = S.view.scale;
    const C = [[c[0], c[1]], [c[1], c[2]]];
    const T = [[Ai[0][0] * C[0][0] + Ai[0][1] * C[1][0], Ai[0][0] * C[0][1] + Ai[0][1] * C[1][1]],
               [Ai[1][0] * C[0][0] + Ai[1][1] * C[1][0], Ai[1][0] * C[0][1] + Ai[1][1] * C[1][1]]];
    const a = s * s * (T[0][0] * Ai[0][0] + T[0][1] * Ai[0][1]);
    const b = s * s * (T[0][0] * Ai[1][0] + T[0][1] * Ai[1][1]);
    const d = s * s * (T[1][0] * Ai[1][0] + T[1][1] * Ai[1][1]);
    const mid = (a + d) / 2, rad = Math.sqrt(((a - d) / 2) ** 2 + b * b);
    const l1 = Math.max(mid + rad, 0), l2 = Math.max(mid - rad, 0);
    return [ELLIPSE_K * Math.sqrt(l1), ELLIPSE_K * Math.sqrt(l2), 0.5 * Math.atan2(2 * b, a - d)];
  }
  function metresPerMapUnit(p = plan()) { return Math.sqrt(Math.abs(p.A[0][0] * p.A[1][1] - p.A[0][1] * p.A[1][0])); }

  // ------------------------------------------------------------------ view
  function resize() {
    const wrap = $("map-wrap"), dpr = window.devicePixelRatio || 1;
    const w = wrap.clientWidth, h = wrap.clientHeight;
    for (const c of [bg, fg]) {
      c.width = Math.max(1, Math.round(w * dpr));
      c.height = Math.max(1, Math.round(h * dpr));
    }
    bgx.setTransform(dpr, 0, 0, dpr, 0, 0);
    fgx.setTransform(dpr, 0, 0, dpr, 0, 0);
    S.view.w = w; S.view.h = h;
    if (!S.view.fitted) fit();
    S.dirtyBg = S.dirtyFg = true;
  }

  /** Fit the plan (or, without one, everything known on this floor) into the view. */
  function fit() {
    const p = plan();
    if (!p) return;
    if (p.width) { showBox([0, 0, p.width, p.height]); return; }
    const pts = [];
    for (const r of S.responders.values()) if (r.pose) pts.push(enuToMap(r.pose.x, r.pose.y));
    for (const c of S.checkpoints) if (c.floor === S.floor) pts.push(enuToMap(c.x, c.y));
    if (pts.length === 0) pts.push(enuToMap(-25, -25), enuToMap(25, 25));
    showPoints(pts);
  }

  /** Zoom to every responder on the shown floor (all responders when none is on it). */
  function fitResponders() {
    let pts = [];
    for (const r of S.responders.values()) if (r.pose && r.pose.floor === S.floor) pts.push(enuToMap(r.pose.x, r.pose.y));
    if (!pts.length) for (const r of S.responders.values()) if (r.pose) pts.push(enuToMap(r.pose.x, r.pose.y));
    if (pts.length) showPoints(pts); else fit();
  }

  function showPoints(pts) {
    const pad = 6 / metresPerMapUnit();  // metres of margin around the outermost points
    showBox([Math.min(...pts.map(q => q[0])) - pad, Math.min(...pts.map(q => q[1])) - pad,
             Math.max(...pts.map(q => q[0])) + pad, Math.max(...pts.map(q => q[1])) + pad]);
  }

  function showBox(box) {
    const V = S.view;
    V.cx = (box[0] + box[2]) / 2; V.cy = (box[1] + box[3]) / 2;
    V.scale = 0.95 * Math.min(V.w / Math.max(box[2] - box[0], 1e-6), V.h / Math.max(box[3] - box[1], 1e-6));
    V.fitted = true;
    S.dirtyBg = S.dirtyFg = true;
  }

  function zoomAt(X, Y, factor) {
    const V = S.view;
    const [u, v] = screenToMap(X, Y);
    V.scale = Math.min(Math.max(V.scale * factor, 1e-3), 200);
    V.cx = u - (X - V.w / 2) / V.scale;
    V.cy = v - (Y - V.h / 2) / V.scale;
    S.dirtyBg = S.dirtyFg = true;
  }

  // ------------------------------------------------------------------ background
  function niceStep(metres) {
    const e = Math.pow(10, Math.floor(Math.log10(metres)));
    for (const m of [1, 2, 5, 10]) if (m * e >= metres) return m * e;
    return 10 * e;
  }

  function drawBackground() {
    const ctx = bgx, V = S.view, p = plan();
    ctx.fillStyle = "#1c1c1c";
    ctx.fillRect(0, 0, V.w, V.h);
    if (!p) return;
    const mpu = metresPerMapUnit(p);
    if (p.img && p.img.complete && p.img.naturalWidth) {
      const [x0, y0] = mapToScreen(0, 0);
      ctx.fillStyle = "#fff";
      ctx.fillRect(x0, y0, p.width * V.scale, p.height * V.scale);
      ctx.imageSmoothingEnabled = V.scale < 1;
      ctx.drawImage(p.img, x0, y0, p.width * V.scale, p.height * V.scale);
    } else {
      drawGrid(ctx, p, mpu);
    }
    // checkpoints of this floor
    ctx.font = "bold 14px system-ui, sans-serif";
    for (const c of S.checkpoints) {
      if (c.floor !== S.floor) continue;
      const [X, Y] = enuToScreen(c.x, c.y);
      ctx.beginPath();
      ctx.moveTo(X, Y - 9); ctx.lineTo(X + 9, Y); ctx.lineTo(X, Y + 9); ctx.lineTo(X - 9, Y); ctx.closePath();
      ctx.fillStyle = "#ffd400"; ctx.fill();
      ctx.lineWidth = 2; ctx.strokeStyle = "#000"; ctx.stroke();
      ctx.lineWidth = 4; ctx.strokeStyle = "#fff"; ctx.strokeText(c.name, X + 12, Y + 5);
      ctx.fillStyle = "#000"; ctx.fillText(c.name, X + 12, Y + 5);
    }
    drawScaleAndNorth(ctx, p, mpu);
  }

  function drawGrid(ctx, p, mpu) {
    const V = S.view;
    ctx.fillStyle = "#f4f4f4";
    ctx.fillRect(0, 0, V.w, V.h);
    const step = niceStep(60 / (V.scale / mpu));  // about 60 px between lines
    const corners = [screenToEnu(0, 0), screenToEnu(V.w, 0), screenToEnu(0, V.h), screenToEnu(V.w, V.h)];
    const xs = corners.map(c => c[0]), ys = corners.map(c => c[1]);
    ctx.lineWidth = 1;
    ctx.font = "12px system-ui, sans-serif";
    ctx.fillStyle = "#444";
    for (let x = Math.floor(Math.min(...xs) / step) * step; x <= Math.max(...xs); x += step) {
      const [X0, Y0] = enuToScreen(x, Math.min(...ys)), [X1, Y1] = enuToScreen(x, Math.max(...ys));
      ctx.strokeStyle = Math.abs(x) < 1e-9 ? "#555" : "#c8c8c8";
      ctx.beginPath(); ctx.moveTo(X0, Y0); ctx.lineTo(X1, Y1); ctx.stroke();
      ctx.fillText(`${+x.toFixed(1)} m`, X0 + 3, 14);  // at the top: the scale bar sits at the bottom
    }
    for (let y = Math.floor(Math.min(...ys) / step) * step; y <= Math.max(...ys); y += step) {
      const [X0, Y0] = enuToScreen(Math.min(...xs), y), [X1, Y1] = enuToScreen(Math.max(...xs), y);
      ctx.strokeStyle = Math.abs(y) < 1e-9 ? "#555" : "#c8c8c8";
      ctx.beginPath(); ctx.moveTo(X0, Y0); ctx.lineTo(X1, Y1); ctx.stroke();
      ctx.fillText(`${+y.toFixed(1)} m`, 4, Y0 - 3);
    }
  }

  function drawScaleAndNorth(ctx, p, mpu) {
    const V = S.view;
    const pxPerM = V.scale / mpu;
    const m = niceStep(120 / pxPerM), len = m * pxPerM;
    const x0 = 16, y0 = V.h - 22;
    ctx.fillStyle = "rgba(0,0,0,0.75)";
    ctx.fillRect(x0 - 8, y0 - 26, len + 90, 40);
    ctx.strokeStyle = "#fff"; ctx.lineWidth = 4;
    ctx.beginPath(); ctx.moveTo(x0, y0); ctx.lineTo(x0 + len, y0); ctx.stroke();
    ctx.fillStyle = "#fff"; ctx.font = "bold 15px system-ui, sans-serif";
    ctx.fillText(`${m} m`, x0 + len + 8, y0 + 5);
    // north arrow
    const [nx, ny] = bearingToScreen(0);
    const cx = V.w - 44, cy = 44;
    ctx.fillStyle = "rgba(0,0,0,0.75)";
    ctx.beginPath(); ctx.arc(cx, cy, 30, 0, 2 * Math.PI); ctx.fill();
    ctx.strokeStyle = "#fff"; ctx.lineWidth = 3;
    ctx.beginPath(); ctx.moveTo(cx - nx * 18, cy - ny * 18); ctx.lineTo(cx + nx * 18, cy + ny * 18); ctx.stroke();
    ctx.beginPath();
    ctx.moveTo(cx + nx * 22, cy + ny * 22);
    ctx.lineTo(cx + nx * 8 - ny * 8, cy + ny * 8 + nx * 8);
    ctx.lineTo(cx + nx * 8 + ny * 8, cy + ny * 8 - nx * 8);
    ctx.closePath(); ctx.fillStyle = "#fff"; ctx.fill();
    ctx.font = "bold 14px system-ui, sans-serif";
    ctx.fillText("N", cx - nx * 26 - 5, cy - ny * 26 + 5);
  }

  // ------------------------------------------------------------------ foreground
  function colorOf(id) {
    let h = 0;
    for (let i = 0; i < id.length; i++) h = (h * 31 + id.charCodeAt(i)) >>> 0;
    return PALETTE[h % PALETTE.length];
  }

  /** Responders with an active alarm, and with one not yet acknowledged (sets, once per use). */
  function alarmSets() {
    const active = new Set(), unacked = new Set();
    for (const a of S.alarms.values()) {
      if (a.active) active.add(a.responder);
      if (!a.acked) unacked.add(a.responder);
    }
    return {active, unacked};
  }

  /** Where each responder is drawn now: live pose, or interpolated on its track in review. */
  function positions() {
    const out = [];
    if (S.mode === "review" && S.review) {
      for (const [id, tr] of S.review.tracks) {
        const n = tr.t.length;
        if (!n) continue;
        const te = tr.t[n - 1] + S.review.offset;
        if (te < tr.t[0]) continue;  // not yet on the track at that time
        let lo = 0, hi = n - 1;
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
    for (const r of S.responders.values()) {
      if (!r.pose) continue;
      const p = r.pose;
      out.push({id: r.id, x: p.x, y: p.y, floor: p.floor, heading: p.heading_deg, cov: p.cov, trail: r.trail, t: p.t});
    }
    return out;
  }

  function drawForeground(now) {
    const ctx = fgx, V = S.view;
    ctx.clearRect(0, 0, V.w, V.h);
    if (!plan()) return;
    const flashOn = Math.floor(now / 500) % 2 === 0;
    const live = S.mode === "live";
    const al = alarmSets();
    const pos = positions();
    const here = [], other = [];
    for (const q of pos) {
      const [X, Y] = enuToScreen(q.x, q.y);
      q.X = X; q.Y = Y;
      (q.floor === S.floor ? here : other).push(q);
    }
    S.drawn = pos;
    // responders on other floors: small and grey, under everything else
    if (S.showOtherFloors && other.length) {
      ctx.fillStyle = "rgba(110,110,110,0.75)";
      ctx.strokeStyle = "#fff"; ctx.lineWidth = 1.5;
      ctx.beginPath();
      for (const q of other) { ctx.moveTo(q.X + 5, q.Y); ctx.arc(q.X, q.Y, 5, 0, 2 * Math.PI); }
      ctx.fill(); ctx.stroke();
    }
    // trails
    ctx.lineWidth = 2.5; ctx.lineJoin = "round";
    ctx.globalAlpha = 0.6;
    for (const q of here) {
      const tr = q.trail;
      if (!tr || tr.length < 2) continue;
      ctx.strokeStyle = colorOf(q.id);
      ctx.beginPath();
      let pen = false;
      for (const pt of tr) {
        if (pt[3] !== S.floor) { pen = false; continue; }
        const [X, Y] = enuToScreen(pt[1], pt[2]);
        if (pen) ctx.lineTo(X, Y); else { ctx.moveTo(X, Y); pen = true; }
      }
      ctx.stroke();
    }
    // uncertainty ellipses
    for (const q of here) {
      if (!q.cov) continue;
      const [r1, r2, ang] = covToEllipse(q.cov);
      if (!(r1 > 2) || r1 > 1e5) continue;
      ctx.beginPath();
      ctx.ellipse(q.X, q.Y, r1, Math.max(r2, 1), ang, 0, 2 * Math.PI);
      const c = colorOf(q.id);
      const vague = r1 > ELLIPSE_FILL_MAX_PX;  // a responder not yet placed: an outline, no tint over the map
      if (!vague) { ctx.globalAlpha = 0.13; ctx.fillStyle = c; ctx.fill(); }
      ctx.globalAlpha = 0.8; ctx.lineWidth = 1.5; ctx.strokeStyle = c;
      if (vague) ctx.setLineDash([8, 6]);
      ctx.stroke();
      if (vague) ctx.setLineDash([]);
    }
    ctx.globalAlpha = 1;
    // markers, heading arrows, alarm halos
    for (const q of here) {
      const alarmed = live && al.active.has(q.id);
      const col = alarmed ? "#e00000" : colorOf(q.id);
      if (live && al.unacked.has(q.id) && flashOn) {
        ctx.beginPath(); ctx.arc(q.X, q.Y, MARKER_R + 11, 0, 2 * Math.PI);
        ctx.lineWidth = 6; ctx.strokeStyle = "#e00000"; ctx.stroke();
      }
      if (q.id === S.selected) {
        ctx.beginPath(); ctx.arc(q.X, q.Y, MARKER_R + 6, 0, 2 * Math.PI);
        ctx.lineWidth = 7; ctx.strokeStyle = "#000"; ctx.stroke();
        ctx.lineWidth = 4; ctx.strokeStyle = "#ffd400"; ctx.stroke();
      }
      if (q.heading !== null && q.heading !== undefined) {
        const [dx, dy] = bearingToScreen(q.heading);
        const tx = q.X + dx * ARROW_LEN, ty = q.Y + dy * ARROW_LEN;
        ctx.beginPath(); ctx.moveTo(q.X, q.Y); ctx.lineTo(tx, ty);
        ctx.lineWidth = 3; ctx.strokeStyle = col; ctx.stroke();
        ctx.beginPath();
        ctx.moveTo(tx + dx * 6, ty + dy * 6);
        ctx.lineTo(tx - dx * 4 - dy * 6, ty - dy * 4 + dx * 6);
        ctx.lineTo(tx - dx * 4 + dy * 6, ty - dy * 4 - dx * 6);
        ctx.closePath(); ctx.fillStyle = col; ctx.fill();
      }
      ctx.beginPath(); ctx.arc(q.X, q.Y, MARKER_R, 0, 2 * Math.PI);
      ctx.fillStyle = col; ctx.fill();
      ctx.lineWidth = 2.5; ctx.strokeStyle = "#fff"; ctx.stroke();
    }
    // labels last, so no marker covers a name
    ctx.font = "bold 15px system-ui, sans-serif";
    ctx.lineWidth = 4; ctx.lineJoin = "round";
    for (const q of here) {
      const lx = q.X + MARKER_R + 4, ly = q.Y - MARKER_R - 2;
      ctx.strokeStyle = "#fff"; ctx.strokeText(q.id, lx, ly);
      ctx.fillStyle = live && al.active.has(q.id) ? "#c00000" : "#000"; ctx.fillText(q.id, lx, ly);
    }
    if (S.pendingPin) {
      const [X, Y] = enuToScreen(S.pendingPin[0], S.pendingPin[1]);
      ctx.beginPath(); ctx.moveTo(X - 14, Y); ctx.lineTo(X + 14, Y); ctx.moveTo(X, Y - 14); ctx.lineTo(X, Y + 14);
      ctx.lineWidth = 6; ctx.strokeStyle = "#000"; ctx.stroke();
      ctx.lineWidth = 3; ctx.strokeStyle = "#ffd400"; ctx.stroke();
    }
  }

  function pushPerf(list, v) { list.push(v); if (list.length > PERF_KEEP) list.shift(); }

  function frame(ts) {
    const P = S.perf;
    if (P.lastRaf !== null) pushPerf(P.frame, ts - P.lastRaf);
    P.lastRaf = ts;
    const now = Date.now();
    const flashing = S.mode === "live" && [...S.alarms.values()].some(a => !a.acked);
    if (flashing && Math.floor(now / 500) !== S.lastFlash) { S.lastFlash = Math.floor(now / 500); S.dirtyFg = true; }
    if (S.dirtyBg || S.dirtyFg) {
      const t0 = performance.now();
      if (S.dirtyBg) { drawBackground(); S.dirtyBg = false; }
      drawForeground(now);
      S.dirtyFg = false;
      pushPerf(P.draw, performance.now() - t0);
    }
    requestAnimationFrame(frame);
  }

  function quantile(list, q) {
    if (!list.length) return null;
    const s = [...list].sort((a, b) => a - b);
    return s[Math.min(s.length - 1, Math.floor(q * s.length))];
  }
  S.perfStats = () => {
    const f = (l) => ({n: l.length, p50: quantile(l, 0.5), p95: quantile(l, 0.95), max: l.length ? Math.max(...l) : null});
    return {draw_ms: f(S.perf.draw), frame_interval_ms: f(S.perf.frame), message_ms: f(S.perf.message)};
  };
  S.resetPerf = () => { S.perf.draw = []; S.perf.frame = []; S.perf.message = []; };

  // ------------------------------------------------------------------ live data
  function responder(id) {
    let r = S.responders.get(id);
    if (!r) {
      r = {id, pose: null, status: null, trail: [], lastRx: 0};
      S.responders.set(id, r);
    }
    return r;
  }

  function applyPose(p) {
    const r = responder(p.responder);
    r.pose = p;
    r.lastRx = Math.max(r.lastRx, p.received_at);
    const last = r.trail[r.trail.length - 1];
    if (!last || last[0] !== p.t || last[1] !== p.x || last[2] !== p.y) {
      r.trail.push([p.t, p.x, p.y, p.floor]);
      if (r.trail.length > S.settings.trail_points) r.trail.splice(0, r.trail.length - S.settings.trail_points);
    }
  }
  function applyStatus(s) {
    const r = responder(s.responder);
    r.status = s;
    r.lastRx = Math.max(r.lastRx, s.received_at);
  }

  function onMessage(ev) {
    const t0 = performance.now();
    const m = JSON.parse(ev.data);
    S.messages++;
    if (m.now) S.clockOffset = m.now - Date.now() / 1000;
    if (m.type === "snapshot") {
      for (const [id, tr] of Object.entries(m.trails || {})) responder(id).trail = tr.slice(-S.settings.trail_points);
      for (const p of m.poses) { const r = responder(p.responder); r.pose = p; r.lastRx = Math.max(r.lastRx, p.received_at); }
      for (const s of m.statuses) applyStatus(s);
      S.rejected = m.rejected || {};
    } else if (m.type === "update") {
      for (const p of m.poses) applyPose(p);
      for (const s of m.statuses) applyStatus(s);
      S.rejected = m.rejected || S.rejected;
    } else if (m.type === "checkpoints") {
      S.checkpoints = m.checkpoints;
      fillCheckpointList();
      S.dirtyBg = true;
    } else if (m.type === "fix") {
      const f = m.fix;
      const where = f.name ? `checkpoint ${f.name}` : `(${f.x.toFixed(1)}, ${f.y.toFixed(1)}) m, floor ${f.floor}`;
      toast(`Fix for ${f.responder} at ${where} sent by the console`, "ok");
    }
    if (m.type === "snapshot" || m.type === "update") {
      S.dirtyFg = true;
      if (!S.view.fitted || (!plan()?.width && S.autoFitPending)) { S.autoFitPending = false; fit(); }
    }
    pushPerf(S.perf.message, performance.now() - t0);
  }

  function connect() {
    const proto = location.protocol === "https:" ? "wss" : "ws";
    const ws = new WebSocket(`${proto}://${location.host}/ws`);
    S.ws = ws;
    ws.onopen = () => { S.connected = true; S.retry = 0; showConnection(); };
    ws.onmessage = onMessage;
    ws.onclose = () => {
      S.connected = false; showConnection();
      S.retry = Math.min((S.retry || 0) + 1, 5);
      setTimeout(connect, 1000 * S.retry);  // back off to 5 s; the page keeps what it had
    };
  }

  function showConnection() {
    const c = $("conn");
    c.className = "conn " + (S.connected ? "ok" : "bad");
    c.textContent = S.connected ? "● CONNECTED" : "NO CONNECTION — RETRYING";
  }

  // ------------------------------------------------------------------ alarms
  function evaluateAlarms() {
    const now = serverNow(), lost = S.settings.lost_contact_s;
    const active = new Map();
    for (const r of S.responders.values()) {
      const kinds = new Set(r.status ? r.status.alarms : []);
      if (r.lastRx && now - r.lastRx > lost) kinds.add("lost_contact");
      for (const k of kinds) active.set(`${r.id}|${k}`, {responder: r.id, kind: k});
    }
    let changed = false;
    for (const [key, a] of active) {
      let e = S.alarms.get(key);
      if (!e) { e = {key, responder: a.responder, kind: a.kind, active: false, acked: false, count: 0}; S.alarms.set(key, e); }
      if (!e.active) { e.active = true; e.acked = false; e.count++; e.raisedAt = now; changed = true; }
    }
    for (const e of [...S.alarms.values()]) {
      if (e.active && !active.has(e.key)) {
        e.active = false; e.clearedAt = now; changed = true;
        if (e.acked) S.alarms.delete(e.key);
      }
    }
    if (changed) S.dirtyFg = true;
    renderAlarms(now);
  }

  function acknowledge(key) {
    const e = S.alarms.get(key);
    if (!e) return;
    e.acked = true;
    if (!e.active) S.alarms.delete(key);
    S.dirtyFg = true;
    renderAlarms(serverNow());
  }

  function ago(s) {
    if (!(s >= 0)) return "—";
    if (s < 60) return `${Math.round(s)} s`;
    if (s < 3600) return `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
    return `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`;
  }

  function renderAlarms(now) {
    const box = $("alarms");
    const list = [...S.alarms.values()].sort((a, b) => (a.acked - b.acked) || (a.raisedAt - b.raisedAt));
    box.hidden = list.length === 0;
    const keep = new Set(list.map(a => a.key));
    for (const el of [...box.children]) if (!keep.has(el.dataset.key)) el.remove();
    list.forEach((a, i) => {
      let el = box.querySelector(`[data-key="${CSS.escape(a.key)}"]`);
      if (!el) {
        el = document.createElement("div");
        el.dataset.key = a.key;
        el.dataset.responder = a.responder;
        el.dataset.kind = a.kind;
        el.innerHTML = '<span class="what"></span><span class="who"></span><span class="when"></span>' +
                       '<span class="state"></span><button class="ack">ACKNOWLEDGE</button>';
        el.querySelector(".ack").addEventListener("click", () => acknowledge(a.key));
        el.querySelector(".who").addEventListener("click", () => select(a.responder, true));
      }
      if (box.children[i] !== el) box.insertBefore(el, box.children[i] || null);
      el.className = "alarm " + (a.acked ? "acked" : "flashing");
      const r = S.responders.get(a.responder);
      const floor = r && r.pose ? ` · floor ${r.pose.floor}` : "";
      setText(el.querySelector(".what"), ALARM_LABELS[a.kind] || a.kind.toUpperCase());
      setText(el.querySelector(".who"), a.responder);
      setText(el.querySelector(".when"), `${floor} · since ${ago(now - a.raisedAt)}` + (a.count > 1 ? ` · ${a.count}×` : ""));
      setText(el.querySelector(".state"), a.active ? (a.acked ? "ACKNOWLEDGED" : "ACTIVE") : "CLEARED");
    });
  }

  function setText(el, text) { if (el.textContent !== text) el.textContent = text; }

  // ------------------------------------------------------------------ roster
  const rows = new Map();
  function rosterValue(r, key, now) {
    switch (key) {
      case "id": return r.id;
      case "floor": return r.pose ? r.pose.floor : -Infinity;
      case "heard": return r.lastRx ? now - r.lastRx : Infinity;
      case "steps": return Math.max(r.pose ? r.pose.steps : 0, r.status ? r.status.steps : 0);
      case "motion": return r.status ? r.status.motion : "";
    }
    return "";
  }

  function renderRoster() {
    const now = serverNow();
    const tbody = $("roster").tBodies[0];
    const list = [...S.responders.values()];
    const {key, dir} = S.sort;
    list.sort((a, b) => {
      const va = rosterValue(a, key, now), vb = rosterValue(b, key, now);
      const c = typeof va === "string" ? va.localeCompare(vb, undefined, {numeric: true}) : va - vb;
      return dir * (c || a.id.localeCompare(b.id, undefined, {numeric: true}));
    });
    for (const [id, tr] of rows) if (!S.responders.has(id)) { tr.remove(); rows.delete(id); }
    const al = alarmSets();
    list.forEach((r, i) => {
      let tr = rows.get(r.id);
      if (!tr) {
        tr = document.createElement("tr");
        tr.dataset.id = r.id;
        tr.innerHTML = "<td></td><td></td><td></td><td></td><td></td>";
        tr.addEventListener("click", () => select(r.id, true));
        rows.set(r.id, tr);
      }
      if (tbody.children[i] !== tr) tbody.insertBefore(tr, tbody.children[i] || null);
      const c = tr.children;
      const heard = rosterValue(r, "heard", now);
      setText(c[0], r.id);
      setText(c[1], r.pose ? String(r.pose.floor) : "—");
      setText(c[2], ago(heard));
      setText(c[3], String(rosterValue(r, "steps", now)));
      setText(c[4], r.status ? (MOTION_LABELS[r.status.motion] || r.status.motion) : "—");
      const cls = [r.id === S.selected ? "selected" : "", al.active.has(r.id) ? "alarmed" : "",
                   r.pose && r.pose.floor !== S.floor ? "other" : "", heard > 5 ? "stale" : ""].join(" ").trim();
      if (tr.className !== cls) tr.className = cls;
    });
    setText($("count"), String(list.length));
    for (const th of $("roster").tHead.rows[0].cells) {
      th.classList.toggle("sorted", th.dataset.key === key);
      th.classList.toggle("desc", th.dataset.key === key && dir < 0);
    }
    renderFloorButtons();
    renderSelection(now);
    const rej = Object.entries(S.rejected).filter(([, n]) => n > 0);
    $("rejected").hidden = rej.length === 0;
    setText($("rejected"), rej.length ? "ignored messages: " + rej.map(([k, n]) => `${k} ${n}`).join(", ") : "");
  }

  function renderFloorButtons() {
    const box = $("floor-buttons");
    const counts = {};
    for (const r of S.responders.values()) if (r.pose) counts[r.pose.floor] = (counts[r.pose.floor] || 0) + 1;
    for (const f of S.floors) {
      let b = box.querySelector(`[data-floor="${f.number}"]`);
      if (!b) {
        b = document.createElement("button");
        b.dataset.floor = f.number;
        b.title = f.name;
        b.innerHTML = `<span class="name"></span><span class="n"></span>`;
        b.addEventListener("click", () => setFloor(f.number));
        box.appendChild(b);
      }
      b.classList.toggle("on", f.number === S.floor);
      setText(b.querySelector(".name"), `${f.number}`);
      setText(b.querySelector(".n"), `· ${counts[f.number] || 0}`);
    }
  }

  function renderSelection(now) {
    const r = S.selected ? S.responders.get(S.selected) : null;
    setText($("sel-id"), S.selected || "none");
    $("btn-fix-cp").disabled = !r || !$("cp-select").value;
    if (!r) { setText($("sel-info"), "Click a marker or a roster row."); return; }
    const p = r.pose, s = r.status;
    const parts = [];
    if (p) parts.push(`floor ${p.floor}`, `x ${p.x.toFixed(1)} m`, `y ${p.y.toFixed(1)} m`, `heading ${Math.round(p.heading_deg)}°`,
                      `±${(ELLIPSE_K * Math.sqrt(Math.max(p.cov[0], p.cov[2]))).toFixed(1)} m`, p.source);
    else parts.push("no position yet (not placed)");
    if (s) parts.push(MOTION_LABELS[s.motion] || s.motion, `${s.frames} frames`);
    setText($("sel-info"), parts.join(" · "));
  }

  // ------------------------------------------------------------------ actions
  function select(id, centre = false) {
    S.selected = id;
    const r = S.responders.get(id);
    if (centre && r && r.pose) {
      if (r.pose.floor !== S.floor && S.plans[r.pose.floor]) setFloor(r.pose.floor);
      const [u, v] = enuToMap(r.pose.x, r.pose.y);
      S.view.cx = u; S.view.cy = v;
      S.dirtyBg = true;
    }
    S.dirtyFg = true;
    renderRoster();
  }

  function setFloor(n) {
    if (!S.plans[n]) return;
    const before = plan();
    const centre = before ? screenToEnu(S.view.w / 2, S.view.h / 2) : null;
    const mpp = before ? metresPerMapUnit(before) / S.view.scale : null;
    S.floor = n;
    const p = plan();
    if (centre) {  // keep the same place and metres per screen pixel across floors
      const [u, v] = enuToMap(centre[0], centre[1]);
      S.view.cx = u; S.view.cy = v; S.view.scale = metresPerMapUnit(p) / mpp;
    }
    const f = S.floors.find(q => q.number === n);
    $("map-notice").textContent = p.url
      ? (p.fallback ? `Floor ${n} (${f.name}) has no plan of its own: showing the plan of floor ${p.plan_floor}.` : "")
      : `Floor ${n} (${f.name}): ${p.problem}. Showing a grid in metres.`;
    S.dirtyBg = S.dirtyFg = true;
    renderFloorButtons();
  }

  function toast(text, kind = "") {
    const el = document.createElement("div");
    el.className = "toast " + kind;
    el.textContent = text;
    $("toasts").appendChild(el);
    while ($("toasts").children.length > 4) $("toasts").firstChild.remove();
    setTimeout(() => el.remove(), kind === "error" ? 12000 : 6000);
  }

  let modalResolve = null;
  function ask(title, text, input = null) {
    $("modal-title").textContent = title;
    $("modal-text").textContent = text;
    const inp = $("modal-input");
    inp.hidden = input === null;
    inp.value = input || "";
    $("modal").hidden = false;
    (input === null ? $("modal-ok") : inp).focus();
    return new Promise((resolve) => { modalResolve = resolve; });
  }
  function closeModal(ok) {
    if ($("modal").hidden) return;
    $("modal").hidden = true;
    const value = $("modal-input").hidden ? true : $("modal-input").value.trim();
    const r = modalResolve; modalResolve = null;
    if (r) r(ok ? value : null);
  }

  async function post(url, body) {
    const res = await fetch(url, {method: "POST", headers: {"Content-Type": "application/json"}, body: JSON.stringify(body)});
    let data = {};
    try { data = await res.json(); } catch (e) { data = {error: `${res.status} ${res.statusText}`}; }
    if (!res.ok) throw new Error(data.error || `${res.status} ${res.statusText}`);
    return data;
  }

  async function fixAtPoint(x, y) {
    const id = S.selected;
    const f = S.floors.find(q => q.number === S.floor);
    S.pendingPin = [x, y]; S.dirtyFg = true;
    const ok = await ask(`Place ${id} here?`,
      `Checkpoint fix for ${id} at x ${x.toFixed(2)} m, y ${y.toFixed(2)} m on floor ${S.floor} (${f.name}). ` +
      `The service corrects ${id}'s track to this point at its latest device time.`);
    S.pendingPin = null; S.dirtyFg = true;
    if (!ok) return;
    try {
      const res = await post("/api/fix", {responder: id, x, y, floor: S.floor});
      toast(`Fix sent for ${id} (device time ${res.sent.t.toFixed(1)} s)`, "ok");
    } catch (e) { toast(`Fix for ${id} not sent: ${e.message}`, "error"); }
  }

  async function fixAtCheckpoint() {
    const id = S.selected, name = $("cp-select").value;
    if (!id || !name) return;
    const ok = await ask(`Place ${id} at ${name}?`, `Checkpoint fix for ${id} at the named checkpoint ${name}.`);
    if (!ok) return;
    try {
      await post("/api/fix", {responder: id, name});
      toast(`Fix sent for ${id} at ${name}`, "ok");
    } catch (e) { toast(`Fix for ${id} not sent: ${e.message}`, "error"); }
  }

  async function addCheckpointAt(x, y) {
    setAddMode(false);
    S.pendingPin = [x, y]; S.dirtyFg = true;
    const name = await ask("Name this checkpoint",
      `New checkpoint at x ${x.toFixed(2)} m, y ${y.toFixed(2)} m on floor ${S.floor}.`, "");
    S.pendingPin = null; S.dirtyFg = true;
    if (!name) return;
    try {
      await post("/api/checkpoint", {name, x, y, floor: S.floor});
      toast(`Checkpoint ${name} added`, "ok");
    } catch (e) { toast(`Checkpoint not added: ${e.message}`, "error"); }
  }

  function setAddMode(on) {
    S.addCheckpoint = on;
    $("btn-add-cp").classList.toggle("on", on);
    $("mode-hint").hidden = !on;
    $("mode-hint").textContent = on ? "CLICK THE MAP WHERE THE NEW CHECKPOINT IS (Esc cancels)" : "";
  }

  function fillCheckpointList() {
    const sel = $("cp-select"), cur = sel.value;
    sel.innerHTML = "";
    const none = document.createElement("option");
    none.value = ""; none.textContent = S.checkpoints.length ? "— named checkpoint —" : "no checkpoints";
    sel.appendChild(none);
    for (const c of S.checkpoints) {
      const o = document.createElement("option");
      o.value = c.name; o.textContent = `${c.name} (floor ${c.floor})`;
      sel.appendChild(o);
    }
    sel.value = S.checkpoints.some(c => c.name === cur) ? cur : "";
    renderSelection(serverNow());
  }

  function hitTest(X, Y) {
    let best = null, bestD = HIT_PX;
    for (const q of S.drawn || []) {
      if (q.floor !== S.floor || q.X === undefined) continue;
      const d = Math.hypot(q.X - X, q.Y - Y);
      if (d < bestD) { best = q; bestD = d; }
    }
    return best;
  }

  function onMapClick(X, Y) {
    const [x, y] = screenToEnu(X, Y);
    if (S.addCheckpoint) { addCheckpointAt(x, y); return; }
    const hit = hitTest(X, Y);
    if (hit) { select(hit.id); return; }
    if (S.mode !== "live") { toast("Fixes are placed in LIVE mode", "error"); return; }
    if (!S.selected) { toast("Select a responder first: click a marker or a roster row", "error"); return; }
    fixAtPoint(x, y);
  }

  // ------------------------------------------------------------------ review
  async function enterReview() {
    let data;
    try {
      const res = await fetch("/api/tracks");
      data = await res.json();
      if (!res.ok) throw new Error(data.error || res.statusText);
    } catch (e) { toast(`Tracks not available: ${e.message}`, "error"); return; }
    const tracks = new Map(Object.entries(data.tracks));
    let span = 0;
    for (const tr of tracks.values()) if (tr.t.length) span = Math.max(span, tr.t[tr.t.length - 1] - tr.t[0]);
    const offset = S.review ? Math.max(S.review.offset, -span) : 0;
    S.review = {tracks, span, offset};
    S.mode = "review";
    const sl = $("scrub");
    sl.min = String(-Math.ceil(span)); sl.max = "0"; sl.value = String(offset);
    $("review-bar").hidden = false;
    $("btn-review").classList.add("on"); $("btn-live").classList.remove("on");
    scrubLabel();
    S.dirtyFg = true;
    resize();
  }
  function leaveReview() {
    S.mode = "live";
    $("review-bar").hidden = true;
    $("btn-live").classList.add("on"); $("btn-review").classList.remove("on");
    S.dirtyFg = true;
    resize();
  }
  function scrubLabel() {
    const o = S.review ? S.review.offset : 0;
    $("scrub-label").textContent = o === 0 ? "latest sample" : `${ago(-o)} before the latest sample`;
  }
  S.setReviewOffset = (o) => { if (S.review) { S.review.offset = o; $("scrub").value = String(o); scrubLabel(); S.dirtyFg = true; } };

  // ------------------------------------------------------------------ input
  function bindInput() {
    let drag = null;
    fg.addEventListener("pointerdown", (e) => {
      fg.setPointerCapture(e.pointerId);
      drag = {x: e.offsetX, y: e.offsetY, cx: S.view.cx, cy: S.view.cy, moved: false, t: performance.now()};
    });
    fg.addEventListener("pointermove", (e) => {
      if (!drag) return;
      const dx = e.offsetX - drag.x, dy = e.offsetY - drag.y;
      if (!drag.moved && Math.hypot(dx, dy) < 6) return;
      drag.moved = true;
      fg.classList.add("panning");
      S.view.cx = drag.cx - dx / S.view.scale;
      S.view.cy = drag.cy - dy / S.view.scale;
      S.dirtyBg = S.dirtyFg = true;
    });
    fg.addEventListener("pointerup", (e) => {
      if (!drag) return;
      const click = !drag.moved;
      drag = null;
      fg.classList.remove("panning");
      if (click) onMapClick(e.offsetX, e.offsetY);
    });
    fg.addEventListener("pointercancel", () => { drag = null; fg.classList.remove("panning"); });
    fg.addEventListener("wheel", (e) => {
      e.preventDefault();
      zoomAt(e.offsetX, e.offsetY, Math.pow(1.0015, -e.deltaY));
    }, {passive: false});
    $("zoom-in").onclick = () => zoomAt(S.view.w / 2, S.view.h / 2, 1.5);
    $("zoom-out").onclick = () => zoomAt(S.view.w / 2, S.view.h / 2, 1 / 1.5);
    $("zoom-fit").onclick = fit;
    $("zoom-all").onclick = fitResponders;
    $("other-floors").onchange = (e) => { S.showOtherFloors = e.target.checked; S.dirtyFg = true; };
    $("btn-fix-cp").onclick = fixAtCheckpoint;
    $("cp-select").onchange = () => renderSelection(serverNow());
    $("btn-add-cp").onclick = () => setAddMode(!S.addCheckpoint);
    $("btn-live").onclick = leaveReview;
    $("btn-review").onclick = enterReview;
    $("btn-review-reload").onclick = enterReview;
    $("scrub").oninput = (e) => S.setReviewOffset(parseFloat(e.target.value));
    $("modal-ok").onclick = () => closeModal(true);
    $("modal-cancel").onclick = () => closeModal(false);
    for (const th of $("roster").tHead.rows[0].cells) {
      th.onclick = () => {
        const k = th.dataset.key;
        S.sort = {key: k, dir: S.sort.key === k ? -S.sort.dir : 1};
        renderRoster();
      };
    }
    document.addEventListener("keydown", (e) => {
      if (!$("modal").hidden) {
        if (e.key === "Escape") closeModal(false);
        else if (e.key === "Enter") closeModal(true);
        return;
      }
      if (e.key === "Escape") { setAddMode(false); }
      else if ((e.key === "f" || e.key === "F") && e.target.tagName !== "INPUT") fit();
      else if ((e.key === "a" || e.key === "A") && e.target.tagName !== "INPUT") fitResponders();
    });
    window.addEventListener("resize", resize);
  }

  // ------------------------------------------------------------------ start
  async function start() {
    bindInput();
    const res = await fetch("/api/incident");
    const inc = await res.json();
    S.incident = inc;
    S.settings = {...S.settings, ...inc.settings};
    S.floors = inc.floors;
    S.checkpoints = inc.checkpoints;
    $("incident-name").textContent = `${inc.name || inc.id}`;
    document.title = `firetrack · ${inc.name || inc.id}`;
    const images = {};
    for (const [floor, p] of Object.entries(inc.plans)) {
      const q = makePlan(p);
      if (q.url) {
        if (!images[q.url]) {
          const img = new Image();
          img.onload = () => { S.dirtyBg = true; S.planLoaded = true; };
          img.onerror = () => toast(`Floor plan ${q.url} could not be loaded; showing a grid`, "error");
          img.src = q.url;
          images[q.url] = img;
        }
        q.img = images[q.url];
      }
      S.plans[Number(floor)] = q;
    }
    S.autoFitPending = true;
    setFloor(S.plans[inc.start_floor] ? inc.start_floor : S.floors[0].number);
    fillCheckpointList();
    resize();
    connect();
    setInterval(renderRoster, ROSTER_PERIOD_MS);  // every period anyway: "heard ... s ago" changes
    setInterval(evaluateAlarms, ALARM_PERIOD_MS);
    setInterval(() => { $("clock").textContent = new Date().toLocaleTimeString([], {hour12: false}); }, 1000);
    requestAnimationFrame(frame);
    S.ready = true;
  }

  // ------------------------------------------------------------------ for tests and tools
  S.enuToScreen = (x, y) => enuToScreen(x, y);
  S.screenToEnu = (X, Y) => screenToEnu(X, Y);
  S.select = (id) => select(id, true);
  S.setFloor = setFloor;
  S.fit = fit;
  S.covToEllipse = covToEllipse;
  S.bearingToScreen = bearingToScreen;
  S.fitResponders = fitResponders;
  S.snapshot = () => {
    const out = {};
    for (const r of S.responders.values()) {
      out[r.id] = {pose: r.pose, status: r.status, trail: r.trail.length, lastRx: r.lastRx};
    }
    return out;
  };
  S.drawnPositions = () => Object.fromEntries((S.drawn || []).map(q => [q.id, {x: q.x, y: q.y, floor: q.floor, X: q.X, Y: q.Y, t: q.t}]));
  S.alarmList = () => [...S.alarms.values()].map(a => ({...a}));

  start().catch((e) => { toast(`The console could not start: ${e.message}`, "error"); console.error(e); });
})();
