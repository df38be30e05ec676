"""A picture per IPIN run: the estimated tracks over the landmarks, on the floor plan when there is one."""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from service.review.ipin_run import IpinRun

THUMB_WIDTH_PX = 2400  # plans are large (the museum's is 10719 px wide); plot a reduced copy


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


def plot_run(run: IpinRun, cfg, folder: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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

    fig, ax = plt.subplots(figsize=(11, 7))
    pts = []
    styles = {"pdr": ("#999999", "dead reckoning"), "live": ("#d62728", "live"), "smoothed": ("#1f77b4", "smoothed")}
    for kind in ("pdr", "live", "smoothed"):
        tr = getattr(run, kind)
        if tr is None or tr["t"].size == 0 or (kind == "pdr" and run.smoothed is None and kind != "live"):
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
    ax.set_title(f"{Path(run.source).name} — {where}; landmark floors {floors}")
    ax.legend(loc="best", fontsize=8)
    target = folder / (Path(run.source).name.split(".")[0] + "_track.png")
    fig.tight_layout()
    fig.savefig(target, dpi=110)
    plt.close(fig)
    return target
