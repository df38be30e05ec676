"""Floor plans as the browser gets them: a downscaled image and its pixel -> ENU map.

A surveyed plan can be far larger than a browser should hold (the IPIN museum's is
10719 x 5069 px, 54 Mpx). The console serves a copy reduced by a whole factor ``f`` (the
smallest that makes it at most :data:`MAX_SERVED_WIDTH_PX` wide and tall). With whole-factor
blocks, served pixel ``(i, j)`` covers exactly the original pixels ``[f i, f (i+1)) x
[f j, f (j+1))``, so with the plan's affine map ``[x, y] = M [u, v, 1]`` (see
:mod:`service.protocol.incident`) the served image's map is exact::

    M_served = M @ diag(f, f, 1)        (u = f u', v = f v')

Line drawings lose thin lines when averaged down, so each block keeps its darkest pixel
(a min-filter, "ink" is preserved) after compositing on white, and a gamma of
:data:`INK_GAMMA` darkens the pale greys architects draw with: high contrast on a laptop
screen in daylight. The copy is made once per process (memoised by file, modification time
and factor) off the event loop.
"""
from __future__ import annotations

import io
import math
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.protocol.incident import FloorPlan, IncidentConfig

MAX_SERVED_WIDTH_PX = 4096  # browsers handle this size well; the museum plan becomes 3573 x 1690
INK_GAMMA = 2.2  # out = 255 (in/255)^gamma: light grey 200 -> 149, white stays white, black stays black
GRID_PX_PER_M = 20.0  # map units per metre on floors without a plan (a grid in metres)


@dataclass(frozen=True)
class ServedPlan:
    """What the page needs to draw the plan of ``floor``: the image URL, its size, its map.

    ``matrix`` (2, 3) maps a served pixel to ENU: ``[x, y] = matrix @ [u, v, 1]``.
    ``plan_floor`` is the floor the image belongs to (another floor's when ``fallback``).
    """

    floor: int
    plan_floor: int
    factor: int
    width: int
    height: int
    matrix: np.ndarray
    fallback: bool
    source: Path

    def to_json(self) -> dict:
        return {"floor": self.floor, "plan_floor": self.plan_floor, "url": f"/plan/{self.plan_floor}.png",
                "width": self.width, "height": self.height, "factor": self.factor,
                "matrix": self.matrix.tolist(), "fallback": self.fallback}


def reduction_factor(width: int, height: int, max_px: int = MAX_SERVED_WIDTH_PX) -> int:
    """Smallest whole ``f`` with ``ceil(W/f) <= max_px`` and ``ceil(H/f) <= max_px``."""
    return max(1, math.ceil(width / max_px), math.ceil(height / max_px))


def served_plan(cfg: IncidentConfig, floor: int, max_px: int = MAX_SERVED_WIDTH_PX) -> ServedPlan | None:
    """The plan the console shows on ``floor`` (its own, or the nearest floor's when it has
    none: :meth:`IncidentConfig.floor_plan` with ``fallback``); None when there is none usable."""
    plan = cfg.floor_plan(floor, fallback=True)
    if plan is None or not plan.available or not plan.georeferenced or plan.size is None:
        return None
    w, h = plan.size
    f = reduction_factor(w, h, max_px)
    m = plan.matrix @ np.diag([float(f), float(f), 1.0])
    return ServedPlan(floor, plan.floor, f, math.ceil(w / f), math.ceil(h / f), m, plan.floor != floor, plan.path)


def plan_problem(cfg: IncidentConfig, floor: int) -> str:
    """Why ``floor`` has no plan to show (for the page's notice)."""
    own = next((p for p in cfg.floor_plans if p.floor == floor), None)
    if own is None:
        return f"no floor plan configured for floor {floor}"
    return own.problem or f"the plan of floor {floor} is unavailable"


def _ink(im) -> np.ndarray:
    """Any Pillow image -> (H, W) uint8 luminance on a white background."""
    from PIL import Image

    if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
        rgba = im.convert("RGBA")
        white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        white.alpha_composite(rgba)
        im = white
    return np.asarray(im.convert("L"))


def downscale_ink(lum: np.ndarray, factor: int, gamma: float = INK_GAMMA) -> np.ndarray:
    """(H, W) uint8 -> (ceil(H/f), ceil(W/f)) uint8: the darkest pixel of each f x f block,
    then ``255 (v/255)^gamma``. The image is padded with white to whole blocks."""
    h, w = lum.shape
    f = int(factor)
    hp, wp = -h % f, -w % f
    if hp or wp:
        lum = np.pad(lum, ((0, hp), (0, wp)), constant_values=255)
    blocks = lum.reshape(lum.shape[0] // f, f, lum.shape[1] // f, f).min(axis=(1, 3))
    lut = np.round(255.0 * (np.arange(256) / 255.0) ** gamma).astype(np.uint8)
    return lut[blocks]


_cache: dict[tuple, bytes] = {}
_cache_lock = threading.Lock()


def plan_png(plan: FloorPlan | ServedPlan, factor: int | None = None) -> bytes:
    """The served copy of a plan image as PNG bytes (greyscale), made once per process."""
    from PIL import Image

    path = Path(plan.source if isinstance(plan, ServedPlan) else plan.path)
    f = int(factor if factor is not None else getattr(plan, "factor", 1))
    key = (str(path), path.stat().st_mtime_ns, f)
    with _cache_lock:  # one thread makes it; the others wait for the bytes instead of making it again
        if key not in _cache:
            with Image.open(path) as im:
                small = downscale_ink(_ink(im), f)
            buf = io.BytesIO()
            Image.fromarray(small).save(buf, format="PNG", compress_level=6)
            _cache[key] = buf.getvalue()
        return _cache[key]


def grid_matrix(px_per_m: float = GRID_PX_PER_M) -> list[list[float]]:
    """The map of a floor without a plan: map units = metres * px_per_m, North up, origin at 0."""
    return [[1.0 / px_per_m, 0.0, 0.0], [0.0, -1.0 / px_per_m, 0.0]]
