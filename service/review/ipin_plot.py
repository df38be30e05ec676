"""A picture per IPIN run that explains it: the track, the heading evidence over time, the floors over time.

* **Track** (left): dead reckoning, the live (published) and the smoothed track over the
  landmarks, on the floor plan when there is one; dotted lines join each scored landmark to
  the live estimate there.
* **Heading** (top right), compass bearings in degrees against time, unwrapped around the dead
  reckoning's: the dead-reckoning heading, the live heading of the graph, and the compass heading
  of travel per step — *used* (the graph's robust kernel kept most of its weight), *down-weighted*
  (it disagreed with the graph by more than the kernel's width: weight below ½) and *rejected*
  by the PDR's gates (field norm, dip, spread, rate: ticks at the top, no value). The black bars
  are the truth: the bearing of the straight line between consecutive landmarks, drawn when the
  walker went further than 4 m between them (a direction, not the path).
* **Floors** (bottom right): the live floor and the dead reckoning's against time, the landmarks'
  floors as circles, and the barometric height (right axis).
"""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from service.review.ipin_run import IpinRun

THUMB_WIDTH_PX = 2400  # plans are large (the museum's is 10719 px wide); plot a reduced copy
TRUTH_MIN_CHORD_M = 4.0  # a landmark-to-landmark line shorter than this says little about the heading
CAUCHY_HALF_WEIGHT = 1.0  # robust weight below which a compass step counts as down-weighted: w = 1/(1+(r/c)^2) < 1/2 <=> |r| > c


@functools.lru_cache(maxsize=4)
def _thumbnail(path: str) -> tuple[np.ndarray, float]:
    """(pixels, scale): the plan reduced to at most THUMB_WIDTH_PX wide, and the reduction factor."""
    from PIL import Image

    Image.MAX_IMAGE_PIXELS = None  # a trusted local plan, not a decompression bomb
    with Image.open(path) as im:
        scale = min(1.0, THUMB_WIDTH_PX / im.size[0])
        size = (max(1, int(im.size[0] * scale)), max(1, int(im.size[1] * scale)))
        small = np.asarray(im.convert("L").resize(size, Image.Resampling.BOX), dtype=float)
    # thin wall lines average out to light grey when reduced: stretch them back to dark
    return np.clip(255.0 - 4.0 * (255.0 - small), 0, 255).astype(np.uint8), scale


def _bearing(yaw):
    return np.degrees(np.pi / 2 - np.asarray(yaw, float))


def _near(ref_deg, deg):
    """``deg`` shifted by whole turns to lie within ±180° of ``ref_deg``."""
    return ref_deg + (np.asarray(deg) - ref_deg + 180.0) % 360.0 - 180.0


def plot_run(run: IpinRun, cfg, folder: Path, kernel_width: float = 1.345) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(16, 8))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.1, 1.0), height_ratios=(1.2, 1.0))
    _track(fig.add_subplot(grid[:, 0]), run, cfg)
    t0 = float(run.lm_t[0])
    _heading(fig.add_subplot(grid[0, 1]), run, t0, kernel_width)
    _floors(fig.add_subplot(grid[1, 1]), run, t0)
    target = folder / (Path(run.source).name.split(".")[0] + "_track.png")
    fig.tight_layout()
    fig.savefig(target, dpi=100)
    plt.close(fig)
    return target


def _track(ax, run: IpinRun, cfg) -> None:
    from service.protocol.incident import enu_to_plan_pixel

    plan = cfg.floor_plan(int(run.lm_floor[0]), fallback=True)
    on_plan = plan is not None and plan.available and plan.georeferenced
    if on_plan:
        img, scale = _thumbnail(str(plan.path))

        def xy(x, y):
            u, v = enu_to_plan_pixel(plan, x, y)
            return np.asarray(u) * scale, np.asarray(v) * scale
    else:
        def xy(x, y):
            return np.asarray(x), np.asarray(y)

    pts = []
    styles = {"pdr": ("#999999", "dead reckoning"), "live": ("#d62728", "live"), "smoothed": ("#1f77b4", "smoothed")}
    for kind in ("pdr", "live", "smoothed"):
        tr = getattr(run, kind)
        if tr is None or tr["t"].size == 0:
            continue
        u, v = xy(tr["x"], tr["y"])
        e = run.errors(kind)
        label = styles[kind][1] + ("" if e is None else f" (p75 {np.percentile(e.error_m, 75):.1f} m)")
        ax.plot(u, v, "-", color=styles[kind][0], lw=1.2 if kind != "pdr" else 0.8, label=label)
        pts.append(np.c_[u, v])
    lu, lv = xy(run.lm_x, run.lm_y)
    pts.append(np.c_[lu, lv])
    scored = run.scored()
    ax.plot(lu[scored], lv[scored], "o", mfc="none", mec="k", ms=7, label="landmarks (scored)")
    ax.plot(lu[run.fixes], lv[run.fixes], "^", color="#2ca02c", ms=8, label="checkpoint fixes")
    e = run.errors("live")
    if e is not None:
        tr = run.live
        i = np.clip(np.searchsorted(tr["t"], run.lm_t[scored], side="right") - 1, 0, None)
        eu, ev = xy(tr["x"][i], tr["y"][i])
        for a, b, c, d in zip(eu, ev, lu[scored], lv[scored]):
            ax.plot([a, c], [b, d], ":", color="#d62728", lw=0.7)
    allp = np.vstack(pts)
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.1 * (hi - lo).max() + (40 if on_plan else 3)
    if on_plan:
        ax.imshow(img, cmap="gray", alpha=0.6)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(hi[1] + pad, lo[1] - pad)  # image rows grow downwards
        ax.set_xticks([])
        ax.set_yticks([])
        where = f"plan of floor {plan.floor}"
    else:
        ax.set_aspect("equal")
        ax.set(xlabel="east (m)", ylabel="north (m)")
        ax.grid(alpha=0.3)
        where = "local ENU"
    floors = sorted(set(run.lm_floor.tolist()))
    ax.set_title(f"{Path(run.source).name} — {where}; landmark floors {floors}", fontsize=9)
    ax.legend(loc="best", fontsize=8)


def _heading(ax, run: IpinRun, t0: float, kernel_width: float) -> None:
    st = run.diagnostics.get("steps")
    if not st or st["t"].size == 0:
        ax.set_title("heading: no steps")
        return
    t = st["t"] - t0
    after = t >= 0
    dr = np.degrees(np.unwrap(np.radians(_bearing(st["heading"]))))
    ax.plot(t[after], dr[after], "-", color="#999999", lw=1.0, label="dead reckoning")
    live_t, live_h = run.live["t"] - t0, run.diagnostics.get("heading")
    if live_h is not None and live_h.size == run.live["t"].size and live_h.size:
        ref = np.interp(live_t, t, dr)
        ax.plot(live_t, _near(ref, _bearing(live_h)), ".", color="#d62728", ms=2, label="live (graph)")
        graph_at_step = np.interp(t, live_t, np.unwrap(np.radians(_bearing(live_h))))
    else:
        graph_at_step = np.radians(dr)
    mag = st["mag_heading"]
    ok = np.isfinite(mag) & after
    if ok.any():
        m = _near(dr[ok], _bearing(mag[ok]))
        sig = np.maximum(np.degrees(st["mag_heading_sigma"][ok]), 1e-6)
        r = np.abs((m - np.degrees(graph_at_step[ok]) + 180.0) % 360.0 - 180.0) / sig
        down = r > kernel_width * CAUCHY_HALF_WEIGHT
        ax.plot(t[ok][~down], m[~down], "o", ms=2.5, color="#2ca02c", label=f"compass, used ({(~down).sum()})")
        ax.plot(t[ok][down], m[down], "x", ms=3.5, color="#ff7f0e", label=f"compass, down-weighted ({down.sum()})")
    rej = ~np.isfinite(mag) & after
    if rej.any():
        top = np.nanmax(dr[after]) + 30.0
        ax.plot(t[rej], np.full(rej.sum(), top), "|", color="#7f7f7f", ms=6, label=f"compass rejected by the PDR ({rej.sum()})")
    for j in range(len(run.lm_t) - 1):
        dx, dy = run.lm_x[j + 1] - run.lm_x[j], run.lm_y[j + 1] - run.lm_y[j]
        if np.hypot(dx, dy) < TRUTH_MIN_CHORD_M:
            continue
        a, b = run.lm_t[j] - t0, run.lm_t[j + 1] - t0
        mid = (a + b) / 2
        ref = float(np.interp(mid, t, dr))
        ax.plot([a, b], [_near(ref, _bearing(np.arctan2(dy, dx)))] * 2, "-", color="k", lw=2.0,
                label="truth: landmark to landmark" if j == 0 else None)
    for j in run.fixes:
        ax.axvline(run.lm_t[j] - t0, color="#2ca02c", lw=0.6, alpha=0.6)
    ax.set(xlabel="time since the first landmark (s)", ylabel="bearing (°, unwrapped)")
    ax.set_title("heading evidence: used, down-weighted, rejected", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=7, ncol=2)


def _floors(ax, run: IpinRun, t0: float) -> None:
    ax.step(run.live["t"] - t0, run.live["floor"], where="post", color="#d62728", lw=1.2, label="live floor")
    ax.step(run.pdr["t"] - t0, run.pdr["floor"], where="post", color="#999999", lw=0.8, ls="--", label="dead reckoning floor")
    ax.plot(run.lm_t - t0, run.lm_floor, "o", mfc="none", mec="k", ms=7, label="landmark floor")
    for t, f in run.diagnostics.get("floor_events", []):
        ax.plot(t - t0, f, "v", color="#9467bd", ms=6)
    fl = sorted(set(run.lm_floor.tolist()) | set(run.live["floor"].tolist()))
    ax.set_yticks(range(min(fl) - 1, max(fl) + 2))
    ax.set(xlabel="time since the first landmark (s)", ylabel="floor")
    ax.grid(alpha=0.3)
    pres = run.diagnostics.get("pressure")
    if pres is not None:
        from pdr.height import relative_height

        pt, pv = pres
        h = relative_height(pv, np.median(pv[: max(1, min(len(pv), 20))]))
        ax2 = ax.twinx()
        ax2.plot(pt - t0, h, color="#1f77b4", lw=0.6, alpha=0.6)
        ax2.set_ylabel("barometric height (m, raw)", color="#1f77b4")
    ax.set_title("floors: estimate against the landmarks (▼ a floor change without a step)", fontsize=9)
    ax.legend(loc="best", fontsize=7)
