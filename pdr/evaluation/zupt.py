"""Scoring a boot-mounted INS against motion capture and ground control points (offline).

Two kinds of PyShoe recordings (:mod:`pdr.io.pyshoe`):

* **Vicon** files carry the foot's position per sample. The track and the reference are
  aligned by the least-squares rigid motion of the plane (SE(2): a rotation and a
  translation, no scale; Umeyama, IEEE TPAMI 13(4), 1991, without the scale step), because
  an INS without a compass knows neither where it started in the room nor its heading.
  Scores: the absolute trajectory error ``ATE = √(mean_i ‖R p_i + t − g_i‖²)`` over every
  sample (as evo's APE on translation), and the final-position error after that alignment
  as a percentage of the distance walked (the path length through the ground control
  points, the stride ends: the per-sample Vicon path is inflated by marker jitter).
* **Hallway** files have no per-sample truth, only ground control points (GCP) at the
  stride ends (``strideIndex``). The track's positions at those samples are aligned to the
  GCP by the same SE(2) fit; scores: mean, maximum and final error at the GCP.

Every figure is computed the same way for the file's ``pyshoeTrajectory`` (the published
PyShoe result, a peer's answer) with its own alignment: the peer gets the same chance.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pdr.events import MotionEvent, StepEvent
from pdr.pipeline import frames_of
from pdr.recording import Recording
from pdr.zupt.motion_model import ZuptMotionModel
from pdr.zupt.settings import ZuptSettings


def se2_fit(est: np.ndarray, ref: np.ndarray) -> tuple[float, np.ndarray]:
    """Rotation angle θ and translation t minimising ``Σ‖R(θ) e_i + t − r_i‖²`` (2-D Umeyama).

    With centred points ``ẽ, r̃`` and ``H = Σ ẽ r̃ᵀ``: ``θ = atan2(H_xy − H_yx, H_xx + H_yy)``,
    ``t = r̄ − R(θ) ē``.
    """
    est = np.asarray(est, float)
    ref = np.asarray(ref, float)
    if est.shape != ref.shape or est.ndim != 2 or est.shape[1] != 2 or est.shape[0] < 2:
        raise ValueError(f"se2_fit needs two (n >= 2, 2) arrays of the same shape, got {est.shape} and {ref.shape}")
    me, mr = est.mean(axis=0), ref.mean(axis=0)
    h = (est - me).T @ (ref - mr)
    theta = math.atan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    c, s = math.cos(theta), math.sin(theta)
    rot = np.array([[c, -s], [s, c]])
    return theta, mr - rot @ me


def se2_apply(theta: float, t: np.ndarray, p: np.ndarray) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    p = np.asarray(p, float)
    return np.column_stack((c * p[:, 0] - s * p[:, 1] + t[0], s * p[:, 0] + c * p[:, 1] + t[1]))


@dataclass
class ZuptRun:
    """What the motion model made of one recording."""

    t: np.ndarray  # (n,) s
    position: np.ndarray  # (n, 3) m, INS frame; samples before the INS started hold its first position
    stationary: np.ndarray  # (n,) bool
    threshold: np.ndarray  # (n,)
    steps: list[StepEvent]
    motion: list[MotionEvent]
    started_at: float  # s, first sample of the INS


def run_zupt(rec: Recording, settings: ZuptSettings | None = None, per_frame: int | None = None) -> ZuptRun:
    """Run :class:`ZuptMotionModel` over a recording (in frames of ``per_frame`` samples, or
    at once) and keep every sample's position."""
    acc, gyr = rec.acc, rec.gyr
    if len(acc) != len(gyr) or not np.array_equal(acc.t, gyr.t):
        raise ValueError(f"{rec.source}: accelerometer and gyro must share their time stamps")
    model = ZuptMotionModel(settings)
    model.track = []
    events = []
    for f in frames_of(acc.t, acc.values, gyr.values, per_frame=per_frame or len(acc)):
        events += model.update(f)
    events += model.finish()
    outs = model.track
    t = np.concatenate([o.t for o in outs])
    pos = np.concatenate([o.position for o in outs])
    ok = np.flatnonzero(np.isfinite(pos[:, 0]))
    if ok.size == 0:
        raise ValueError(f"{rec.source}: the INS never started (no still window of "
                         f"{model.settings.ins.init_still_s} s)")
    pos[: ok[0]] = pos[ok[0]]
    return ZuptRun(t=t, position=pos, stationary=np.concatenate([o.stationary for o in outs]),
                   threshold=np.concatenate([o.threshold for o in outs]),
                   steps=[e for e in events if isinstance(e, StepEvent)],
                   motion=[e for e in events if isinstance(e, MotionEvent)], started_at=float(t[ok[0]]))


@dataclass
class TrackScore:
    """The scores of one track against one reference (see the module docstring)."""

    ate_rmse_m: float = math.nan  # Vicon files
    final_error_m: float = math.nan
    final_error_pct: float = math.nan  # of the distance walked
    gcp_mean_m: float = math.nan  # hallway files (also computed on Vicon files)
    gcp_max_m: float = math.nan
    gcp_final_m: float = math.nan
    aligned: np.ndarray | None = field(default=None, repr=False)  # (n, 2) the aligned track

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "aligned"}


@dataclass
class FileScore:
    source: str
    kind: str  # "vicon" or "gcp"
    samples: int
    duration_s: float
    distance_m: float  # through the ground control points
    strides: int  # stride events of the model
    gcp: int  # ground control points
    ours: TrackScore
    pyshoe: TrackScore | None
    run: ZuptRun = field(repr=False)

    def as_dict(self) -> dict:
        return {"file": self.source, "kind": self.kind, "samples": self.samples, "duration_s": self.duration_s,
                "distance_m": self.distance_m, "strides": self.strides, "gcp": self.gcp, "ours": self.ours.as_dict(),
                "pyshoe": None if self.pyshoe is None else self.pyshoe.as_dict()}


def score_track(xy: np.ndarray, rec: Recording) -> TrackScore:
    """Scores of a per-sample track ``xy`` (n, 2) against the recording's references."""
    s = TrackScore()
    idx = rec.meta.get("stride_index")
    gcp = rec.meta.get("gcp")
    distance = _distance(rec)
    if rec.position_ref is not None:
        ref = rec.position_ref.values
        ok = np.isfinite(xy).all(axis=1) & np.isfinite(ref).all(axis=1)
        theta, tr = se2_fit(xy[ok], ref[ok])
        al = se2_apply(theta, tr, xy)
        err = np.linalg.norm(al[ok] - ref[ok], axis=1)
        s.ate_rmse_m = float(np.sqrt(np.mean(err * err)))
        s.final_error_m = float(np.linalg.norm(al[-1] - ref[-1]))
        s.aligned = al
    if idx is not None and gcp is not None and len(idx) >= 2:
        ok = np.isfinite(xy[idx]).all(axis=1) & np.isfinite(gcp).all(axis=1)
        theta, tr = se2_fit(xy[idx][ok], gcp[ok])
        al = se2_apply(theta, tr, xy)
        e = np.linalg.norm(al[idx][ok] - gcp[ok], axis=1)
        s.gcp_mean_m, s.gcp_max_m, s.gcp_final_m = float(e.mean()), float(e.max()), float(e[-1])
        if rec.position_ref is None:
            s.final_error_m = s.gcp_final_m
            s.aligned = al
    if distance > 0 and math.isfinite(s.final_error_m):
        s.final_error_pct = 100.0 * s.final_error_m / distance
    return s


def _distance(rec: Recording) -> float:
    """Distance walked (m): the path through the ground control points, else the reference's."""
    gcp = rec.meta.get("gcp")
    if gcp is not None and len(gcp) >= 2:
        d = np.diff(gcp[np.isfinite(gcp).all(axis=1)], axis=0)
        return float(np.sum(np.hypot(d[:, 0], d[:, 1])))
    if rec.position_ref is not None:
        d = np.diff(rec.position_ref.values, axis=0)
        return float(np.sum(np.hypot(d[:, 0], d[:, 1])))
    return math.nan


def score_recording(rec: Recording, settings: ZuptSettings | None = None, per_frame: int | None = None) -> FileScore:
    """Run the model on one PyShoe recording and score it and the file's PyShoe track."""
    run = run_zupt(rec, settings, per_frame)
    ours = score_track(run.position[:, :2], rec)
    peer = rec.meta.get("pyshoe_trajectory")
    theirs = score_track(peer, rec) if peer is not None else None
    kind = "vicon" if rec.position_ref is not None else "gcp"
    t = rec.acc.t
    return FileScore(source=rec.source, kind=kind, samples=len(t), duration_s=float(t[-1] - t[0]),
                     distance_m=_distance(rec), strides=len(run.steps), gcp=len(rec.meta.get("gcp", [])),
                     ours=ours, pyshoe=theirs, run=run)


def summary(scores: list[FileScore]) -> dict:
    """Means (and medians) over the files of each kind, ours next to PyShoe's."""
    out: dict = {}
    for kind, keys in (("vicon", ("ate_rmse_m", "final_error_pct")), ("gcp", ("gcp_mean_m", "gcp_final_m",
                                                                             "final_error_pct"))):
        sel = [s for s in scores if s.kind == kind]
        if not sel:
            continue
        block = {"files": len(sel), "distance_m": float(sum(s.distance_m for s in sel))}
        for who in ("ours", "pyshoe"):
            vals = {}
            for k in keys:
                v = np.array([getattr(getattr(s, who), k) if getattr(s, who) is not None else math.nan for s in sel])
                vals[f"mean_{k}"] = float(np.nanmean(v)) if np.isfinite(v).any() else math.nan
                vals[f"median_{k}"] = float(np.nanmedian(v)) if np.isfinite(v).any() else math.nan
            block[who] = vals
        out[kind] = block
    return out


def cross_validate(errors: np.ndarray, groups: np.ndarray | None = None) -> dict:
    """Held-out error of choosing a configuration by its mean error on the other files.

    ``errors`` (configurations, files). For each group of files (each file alone when
    ``groups`` is None: leave-one-out), the configuration with the lowest mean error over
    the files outside the group is chosen, and its error on the group's files is kept.
    Returns the mean and median of the kept errors and, per file, the chosen configuration.
    """
    errors = np.asarray(errors, float)
    n_cfg, n_files = errors.shape
    groups = np.arange(n_files) if groups is None else np.asarray(groups)
    held = np.full(n_files, np.nan)
    chosen = np.full(n_files, -1)
    for g in np.unique(groups):
        test = groups == g
        if test.all():
            raise ValueError("cross-validation needs at least two groups")
        best = int(np.argmin(errors[:, ~test].mean(axis=1)))
        held[test] = errors[best, test]
        chosen[test] = best
    return {"mean": float(held.mean()), "median": float(np.median(held)), "held_out": held, "chosen": chosen}
