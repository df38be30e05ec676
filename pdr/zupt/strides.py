"""From one stance of the boot to the next: the stride, its uncertainty and its gait class.

The INS (:class:`pdr.zupt.ins.ZuptIns`) reports its state once per stance. Between two
stances ``k−1`` and ``k`` the boot moved by ``d = p_k − p_{k−1}``; that stride becomes one
:class:`pdr.events.StepEvent`, the same record the handheld pipeline emits, so the factor
graph, floors, fixes, alarms and console take it unchanged:

* ``length = ‖(d_x, d_y)‖``, ``heading = atan2(d_y, d_x)`` (ENU yaw of travel, in the INS's
  frame), ``heading_change = heading_k − heading_{k−1}`` wrapped to (−π, π];
* ``dz = d_z`` (stairs come out as vertical displacement);
* uncertainties from the filter: the growth of the position covariance over the stride,
  ``Σ_d = Σ_p(k) − Σ_p(k−1)`` (a first-order increment: the filter does not carry the
  cross-covariance of two stances), split along and across the direction of travel,
  ``σ_L² = uᵀΣ_d u + (σ_0 + k·L)²``, ``σ_Δψ² = (σ²_ψ(k) − σ²_ψ(k−1)) + nᵀΣ_d n / L²``,
  ``σ_dz² = Σ_d,zz + σ_z0²``. The floors ``σ_0 + k·L`` and ``σ_z0`` cover what the
  filter does not model (a ZUPT INS stride on Vicon reads about 2 % short).

A stride shorter than ``heading_min_length_m`` (turning on the spot, shuffling) keeps the
previous direction of travel: its own direction is noise.

Gait class per stride (:class:`pdr.zupt.settings.GaitSettings`): crawling (boot resting
tilted), stairs (|dz| per stride), running (short stride time or a hard impact), walking.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pdr.angles import wrap
from pdr.events import MotionState
from pdr.zupt.ins import Stances
from pdr.zupt.settings import GaitSettings, StrideSettings


@dataclass(frozen=True)
class Stride:
    """One stride of one boot, between two stances."""

    t: float  # s, time of the stance that ends it
    duration: float  # s, since the previous stance
    dx: float  # m, ENU (INS frame)
    dy: float
    dz: float
    length: float  # m, horizontal
    length_sigma: float  # m
    heading: float  # rad, ENU yaw of travel (INS frame)
    heading_change: float  # rad, since the previous stride
    heading_change_sigma: float  # rad
    dz_sigma: float  # m
    yaw_sigma: float  # rad, of the INS's yaw (not counting the unknown start)
    peak_acc: float  # m/s², largest ‖f‖ of the stride
    tilt: float  # rad, the boot's tilt at the stance from its attitude at the start
    gait: MotionState


def classify(duration: float, dz: float, peak_acc: float, tilt: float, g: GaitSettings) -> MotionState:
    """Gait class of one stride (crawling, stairs, running or walking)."""
    if tilt >= g.crawl_tilt:
        return MotionState.CRAWLING
    if abs(dz) >= g.stairs_min_dz_m:
        return MotionState.STAIRS
    if duration <= g.run_max_stride_s or peak_acc >= g.run_min_peak_m_s2:
        return MotionState.RUNNING
    return MotionState.WALKING


class StrideMaker:
    """Streaming: ``strides = maker.update(stances)``; the first stance only sets the origin."""

    def __init__(self, stride: StrideSettings | None = None, gait: GaitSettings | None = None):
        self.stride_settings = stride or StrideSettings()
        self.gait_settings = gait or GaitSettings()
        self._prev: tuple | None = None  # (t, p (3,), cov (3, 3), yaw_var) of the previous stance
        self._heading = math.nan

    @property
    def origin_known(self) -> bool:
        return self._prev is not None

    def update(self, st: Stances) -> list[Stride]:
        out: list[Stride] = []
        s, g = self.stride_settings, self.gait_settings
        for i in range(len(st)):
            t = float(st.t[i])
            p = st.position[i]
            cov = st.position_cov[i]
            yv = float(st.yaw_var[i])
            if self._prev is None:
                self._prev = (t, p, cov, yv)
                continue
            t0, p0, cov0, yv0 = self._prev
            self._prev = (t, p, cov, yv)
            dx, dy, dz = float(p[0] - p0[0]), float(p[1] - p0[1]), float(p[2] - p0[2])
            length = math.hypot(dx, dy)
            if length >= s.heading_min_length_m or math.isnan(self._heading):
                heading = math.atan2(dy, dx)
            else:
                heading = self._heading
            change = 0.0 if math.isnan(self._heading) else wrap(heading - self._heading)
            self._heading = heading
            dcov = cov - cov0
            c, sn = math.cos(heading), math.sin(heading)
            along = max(c * c * dcov[0, 0] + 2 * c * sn * dcov[0, 1] + sn * sn * dcov[1, 1], 0.0)
            across = max(sn * sn * dcov[0, 0] - 2 * c * sn * dcov[0, 1] + c * c * dcov[1, 1], 0.0)
            floor_l = s.length_sigma_m + s.length_sigma_frac * length
            length_sigma = math.sqrt(along + floor_l * floor_l)
            turn_var = max(yv - yv0, 0.0) + across / max(length, s.heading_min_length_m) ** 2
            turn_sigma = max(math.sqrt(turn_var), s.heading_change_sigma_floor)
            dz_sigma = math.sqrt(max(float(dcov[2, 2]), 0.0) + s.dz_sigma_m ** 2)
            duration = t - t0
            peak, tilt = float(st.peak_acc[i]), float(st.tilt[i])
            out.append(Stride(t, duration, dx, dy, dz, length, length_sigma, heading, change, turn_sigma, dz_sigma,
                              math.sqrt(max(yv, 0.0)), peak, tilt, classify(duration, dz, peak, tilt, g)))
        return out


def stride_arrays(strides: list[Stride]) -> dict[str, np.ndarray]:
    """Columns of a list of strides (for evaluation and plots)."""
    names = [f for f in Stride.__dataclass_fields__ if f != "gait"]
    cols = {n: np.array([getattr(s, n) for s in strides], dtype=float) for n in names}
    cols["gait"] = np.array([s.gait.value for s in strides], dtype=object)
    return cols
