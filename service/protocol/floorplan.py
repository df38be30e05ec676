"""Floor plans and their georeference: image pixels to the incident's local ENU frame.

Floor plans
-----------
An image pixel is ``(u, v)``: ``u`` to the right, ``v`` down, in pixels from the image's
top-left corner (pixel ``(i, j)`` covers ``[i, i+1) x [j, j+1)``, so the image centre is
``(W/2, H/2)``). A plan's georeference is an affine map pixel -> ENU,
``[x, y] = A [u, v] + b``, given either

* IPIN ``.cal`` style: the image centre's ``centre_lat``/``centre_lon``, ``metres_per_pixel``
  ``s`` and ``rotation_deg`` ``r``, the compass bearing of the image's "up" (clockwise from
  North; the IPIN 2023 museum's -20.736 deg puts up 20.7 deg west of North, which is what
  lines the surveyed reference points of ``floormap_references.csv`` up with the dots drawn
  on ``Map_Floor_-01.png``). With ``phi = -r`` (counter-clockwise)::

      a = s (u - W/2),  b = s (H/2 - v)                 (image right, image up; m)
      x = x_c + a cos(phi) - b sin(phi)
      y = y_c + a sin(phi) + b cos(phi)                  ((x_c, y_c) the centre in ENU)

  It needs the image size, read from the image or given as ``size_px``. The plane of the
  image is taken as the ENU plane: over a building (100 m) the two differ by far less than a
  pixel's worth of metres.
* control points: two or more ``{u, v}`` with ``{x, y}`` or ``{lat, lon}``. Two give a
  similarity (scale, rotation, shift; ``v`` flipped); three or more a least-squares affine map.

A plan whose image is missing still loads: ``available`` is False and ``problem`` says why, so
a console can draw without it.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, model_validator
from pydantic_core import PydanticCustomError


class _Config(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, validate_assignment=False)


class ControlPoint(_Config):
    """A pixel ``u, v`` of a plan and where it is: ``x, y`` (ENU, m) or ``lat, lon`` (deg)."""

    u: float
    v: float
    x: float | None = None
    y: float | None = None
    lat: float | None = Field(None, ge=-90.0, le=90.0)
    lon: float | None = Field(None, ge=-180.0, le=180.0)

    @model_validator(mode="after")
    def _one_position(self) -> ControlPoint:
        enu, geo = self.x is not None and self.y is not None, self.lat is not None and self.lon is not None
        if enu == geo or (self.x is None) != (self.y is None) or (self.lat is None) != (self.lon is None):
            raise PydanticCustomError("position", "a control point needs either x, y or lat, lon")
        return self


class Georeference(_Config):
    """Either the IPIN ``.cal`` four (``centre_lat``, ``centre_lon``, ``rotation_deg``,
    ``metres_per_pixel``) or ``control_points`` (see the module docstring)."""

    centre_lat: float | None = Field(None, ge=-90.0, le=90.0)
    centre_lon: float | None = Field(None, ge=-180.0, le=180.0)
    rotation_deg: float | None = None
    metres_per_pixel: float | None = Field(None, gt=0.0)
    control_points: list[ControlPoint] | None = Field(None, max_length=1000)

    @model_validator(mode="after")
    def _one_style(self) -> Georeference:
        cal = ("centre_lat", "centre_lon", "rotation_deg", "metres_per_pixel")
        given = [f for f in cal if getattr(self, f) is not None]
        if self.control_points is not None:
            if given:
                raise PydanticCustomError("georeference", "give either control_points or {cal}, not both",
                                          {"cal": ", ".join(cal)})
            if len(self.control_points) < 2:
                raise PydanticCustomError("georeference", "control_points: need at least 2, got {n}",
                                          {"n": len(self.control_points)})
        elif len(given) != len(cal):
            missing = [f for f in cal if f not in given]
            raise PydanticCustomError("georeference", "needs {cal} (missing: {missing}) or control_points",
                                      {"cal": ", ".join(cal), "missing": ", ".join(missing)})
        return self

    @property
    def is_cal(self) -> bool:
        return self.control_points is None


class FloorPlan(_Config):
    """A floor's plan image and its georeference. ``image`` relative to the config file."""

    floor: int
    image: str = Field(min_length=1, max_length=4096)
    georeference: Georeference
    size_px: tuple[int, int] | None = Field(None, description="image width, height in pixels (read from the image if absent)")

    _path: Path | None = PrivateAttr(None)
    _available: bool = PrivateAttr(False)
    _problem: str | None = PrivateAttr(None)
    _size: tuple[int, int] | None = PrivateAttr(None)
    _matrix: np.ndarray | None = PrivateAttr(None)  # (2, 3): [x, y] = M @ [u, v, 1]

    @property
    def path(self) -> Path | None:
        """The image file, resolved against the config file's folder."""
        return self._path

    @property
    def available(self) -> bool:
        """True when the image file exists and could be read."""
        return self._available

    @property
    def problem(self) -> str | None:
        """Why the image (or its georeference) is unavailable."""
        return self._problem

    @property
    def size(self) -> tuple[int, int] | None:
        """(width, height) in pixels, when known."""
        return self._size

    @property
    def georeferenced(self) -> bool:
        return self._matrix is not None

    @property
    def matrix(self) -> np.ndarray:
        """The (2, 3) affine matrix pixel -> ENU: ``[x, y] = M @ [u, v, 1]``."""
        if self._matrix is None:
            raise ValueError(f"the plan of floor {self.floor} has no usable georeference: {self._problem}")
        return self._matrix


def resolve_plan(plan: FloorPlan, base_dir: Path, to_enu) -> list[str]:
    """Find the plan's image (relative to ``base_dir``), read its size and work out its
    georeference; the problems found, as ``field: what`` strings (none: all is well)."""
    path = Path(plan.image).expanduser()
    plan._path = path if path.is_absolute() else (base_dir / path).resolve()
    plan._size = tuple(plan.size_px) if plan.size_px is not None else None
    if not plan._path.is_file():
        plan._available, plan._problem = False, f"image {plan._path} not found"
    else:
        try:
            size = _image_size(plan._path)
        except Exception as e:  # a corrupt or unsupported image: the plan is unavailable, the config still loads
            plan._available, plan._problem = False, f"image {plan._path} unreadable: {e}"
        else:
            if plan.size_px is not None and tuple(plan.size_px) != size:
                return [f"size_px: {list(plan.size_px)} but {plan._path.name} is {size[0]} x {size[1]} pixels"]
            plan._available, plan._size = True, size
    g = plan.georeference
    try:
        if g.is_cal:
            if plan._size is None:
                why = "image size unknown (give size_px), so the .cal centre cannot be placed"
                plan._problem = f"{plan._problem}; {why}" if plan._problem else why
                return []
            plan._matrix = cal_matrix(g, plan._size, to_enu)
        else:
            plan._matrix = control_point_matrix(g.control_points, to_enu)
    except ValueError as e:
        return [f"georeference: {e}"]
    return []


def cal_matrix(g: Georeference, size: tuple[int, int], to_enu) -> np.ndarray:
    """The .cal style: image centre, scale and rotation (see the module docstring)."""
    xc, yc, _ = to_enu(g.centre_lat, g.centre_lon)
    s, phi = g.metres_per_pixel, math.radians(-g.rotation_deg)
    c, sn = math.cos(phi), math.sin(phi)
    a = np.array([[s * c, s * sn], [s * sn, -s * c]])  # d[x, y] / d[u, v], from the docstring's equations
    centre = np.array([size[0] / 2.0, size[1] / 2.0])
    return np.column_stack([a, np.array([xc, yc]) - a @ centre])


def control_point_matrix(points: list[ControlPoint], to_enu) -> np.ndarray:
    """Two control points: a similarity; three or more: a least-squares affine map."""
    uv = np.array([[p.u, p.v] for p in points], dtype=np.float64)
    xy = np.array([[p.x, p.y] if p.x is not None else to_enu(p.lat, p.lon)[:2] for p in points], dtype=np.float64)
    if len(points) == 2:
        # similarity with v flipped: x + iy = alpha (u - iv) + beta
        w = uv[:, 0] - 1j * uv[:, 1]
        z = xy[:, 0] + 1j * xy[:, 1]
        if abs(w[1] - w[0]) < 1e-9 or abs(z[1] - z[0]) < 1e-9:
            raise ValueError("the two control points must differ in pixels and in position")
        alpha = (z[1] - z[0]) / (w[1] - w[0])
        beta = z[0] - alpha * w[0]
        return np.array([[alpha.real, alpha.imag, beta.real], [alpha.imag, -alpha.real, beta.imag]])
    design = np.column_stack([uv, np.ones(len(points))])
    if np.linalg.matrix_rank(design, tol=1e-6 * max(1.0, np.abs(uv).max())) < 3:
        raise ValueError("control points are collinear in the image")
    sol, *_ = np.linalg.lstsq(design, xy, rcond=None)
    m = sol.T
    if abs(np.linalg.det(m[:, :2])) < 1e-12:
        raise ValueError("control points give a degenerate map (their positions are collinear)")
    return m

    # -- frames -------------------------------------------------------------------------


def _scalar_or_array(v):
    return float(v) if np.ndim(v) == 0 else np.asarray(v, dtype=np.float64)


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the image header (Pillow opens lazily: no pixels are decoded)."""
    from PIL import Image

    with Image.open(path) as im:
        return int(im.size[0]), int(im.size[1])


def plan_pixel_to_enu(plan: FloorPlan, u, v):
    """Image pixel ``(u, v)`` (right, down from the top-left corner) -> local ENU ``(x, y)`` m."""
    m = plan.matrix
    u, v = np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64)
    x = m[0, 0] * u + m[0, 1] * v + m[0, 2]
    y = m[1, 0] * u + m[1, 1] * v + m[1, 2]
    return _scalar_or_array(x), _scalar_or_array(y)


def enu_to_plan_pixel(plan: FloorPlan, x, y):
    """Local ENU ``(x, y)`` m -> image pixel ``(u, v)`` (the inverse of :func:`plan_pixel_to_enu`)."""
    m = plan.matrix
    inv = np.linalg.inv(m[:, :2])
    dx = np.asarray(x, dtype=np.float64) - m[0, 2]
    dy = np.asarray(y, dtype=np.float64) - m[1, 2]
    return _scalar_or_array(inv[0, 0] * dx + inv[0, 1] * dy), _scalar_or_array(inv[1, 0] * dx + inv[1, 1] * dy)


