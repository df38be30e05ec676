"""Walking direction relative to the device's forward axis, from the acceleration of walking.

A phone is not always carried with its forward axis (y) along the walk. Over a window of
``window`` seconds the horizontal linear acceleration in the levelled frame, expressed in the
device-heading frame (``a_f`` along the device's forward axis, ``a_l`` to its left), swings
mostly fore-aft: the principal axis of its 2×2 covariance (PCA; Kourogi & Kurata 2003,
Combettes & Renaudin, "Comparison of misalignment estimation techniques between handheld
device and walking directions", IPIN 2015) is the walking axis, angle ``α`` from forward,
known only modulo π.

The π ambiguity is resolved from the gait's phase: the body speeds up forward while the
centre of mass falls after mid-stance, so along the true forward direction ``u`` the
statistic

    c = E[a_u(t + τ) a_z(t)] − E[a_u(t) a_z(t + τ)],     τ ≈ a quarter step (``lag``)

has a fixed sign (negative with this definition: on all 37 IPIN 2023 hand-held walks it was
negative in 99 % of the legs when ``u`` is the phone's y axis). A positive majority over the
window says the device's forward axis points backwards.

Modes: ``"flip"`` (default) returns 0 or π only — the phase test decides whether the phone is
carried reversed; ``"pca"`` returns the full principal-axis angle with the sign from the phase
test. Measured on the IPIN logs, the PCA angle of a hand-held phone is noisier (per-leg
median |error| 13° vs 10°) than assuming the phone points where the walker goes, so ``pca``
suits other carry modes (swinging hand, pocket), not texting.

Streaming: the last ``window`` seconds of samples are kept; offsets are per step, computed on
the samples up to the step time, so batching does not change them.
"""
from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from pdr.heading_kernels import walking_stats


@dataclasses.dataclass(frozen=True)
class WalkingDirectionSettings:
    mode: str = "flip"  # "flip" (0 or π) or "pca" (full angle)
    window: float = 3.0  # s of samples per decision
    lag: float = 0.125  # s, about a quarter of a step period
    min_samples: int = 50  # fewer samples in the window: offset 0


class WalkingDirection:
    """``update(t, acc_nav, device_yaw, step_times) -> offsets`` (rad, walking − device, CCW).

    ``acc_nav`` (N, 3) is the specific force in a levelled frame (z up, m/s²; gravity may be
    left in, it is removed with the window mean), ``device_yaw`` (N,) the yaw of the device's
    forward axis in that same frame (rad).
    """

    def __init__(self, settings: WalkingDirectionSettings | None = None):
        self.settings = settings or WalkingDirectionSettings()
        if self.settings.mode not in ("flip", "pca"):
            raise ValueError(f"unknown mode {self.settings.mode!r}; expected 'flip' or 'pca'")
        self._buf = {"t": np.empty(0), "f": np.empty(0), "l": np.empty(0), "z": np.empty(0)}
        self._pending: list[float] = []

    def update(self, t, acc_nav, device_yaw, step_times=()) -> tuple[np.ndarray, np.ndarray]:
        """Returns ``(step_t, offset)`` for the steps whose samples have all arrived."""
        t = np.asarray(t, float).reshape(-1)
        a = np.asarray(acc_nav, float).reshape(-1, 3)
        psi = np.asarray(device_yaw, float).reshape(-1)
        c, s = np.cos(psi), np.sin(psi)
        new = {"t": t, "f": c * a[:, 0] + s * a[:, 1], "l": -s * a[:, 0] + c * a[:, 1], "z": a[:, 2]}
        B = {k: np.concatenate([self._buf[k], new[k]]) for k in new}
        self._pending = sorted(self._pending + [float(x) for x in np.asarray(step_times, float).reshape(-1)])
        t_last = B["t"][-1] if len(B["t"]) else -math.inf
        ready = [x for x in self._pending if x <= t_last]
        self._pending = [x for x in self._pending if x > t_last]
        out = np.array([self._offset(B, tk) for tk in ready])
        if len(B["t"]):
            horizon = B["t"][-1] - self.settings.window - 1e-9
            keep = B["t"] > min([horizon] + self._pending)
            B = {k: v[keep] for k, v in B.items()}
        self._buf = B
        return np.array(ready), out

    def _offset(self, B, tk) -> float:
        s = self.settings
        sel = (B["t"] > tk - s.window) & (B["t"] <= tk)
        if sel.sum() < s.min_samples:
            return 0.0
        return walking_angle(B["t"][sel], B["f"][sel], B["l"][sel], B["z"][sel], s.lag, s.mode == "pca").angle


class WalkingAxis(NamedTuple):
    """One window's walking direction (:func:`walking_angle`)."""

    angle: float  # α, rad, CCW from the device's forward axis, in (−π, π]
    anisotropy: float  # e = (λ₁ − λ₂)/(λ₁ + λ₂) of the horizontal swing, 0..1
    phase: float  # |c| / (σ_u σ_z): how clearly the gait's phase shows (0: not at all)
    vertical_std: float  # σ_z, m/s², the vertical specific force's spread (a walk: about 1)


def walking_angle(t, f, l, z, lag: float, pca: bool = True) -> WalkingAxis:
    """Walking direction from one window of levelled specific force in the device-heading frame.

    ``f``, ``l``, ``z`` (m/s², forward, left, up; means are removed here), ``t`` their times (s).
    ``angle`` is from the device's forward axis to the walking direction (with ``pca=False``
    only 0 or π); the other fields say how far the window looks like walking.

    The principal axis of the 2×2 covariance ``C`` of (f, l) in closed form,
    ``α₀ = ½ atan2(2 C_fl, C_ff − C_ll)``, ``λ₁,₂ = ½ (C_ff + C_ll) ± ½ √((C_ff − C_ll)² + 4 C_fl²)``,
    so ``e = √((C_ff − C_ll)² + 4 C_fl²) / (C_ff + C_ll)``; no eigen-solver, so the bits do not
    depend on a BLAS. The sign from the phase test of the module docstring (``c > 0``: add π),
    with ``u`` the swing along ``α₀`` and the lag in samples from the window's mean interval.
    One compiled call (:func:`pdr.heading_kernels.walking_stats`): it runs once per step of
    every responder.
    """
    return WalkingAxis(*walking_stats(np.ascontiguousarray(t, float), np.ascontiguousarray(f, float),
                                      np.ascontiguousarray(l, float), np.ascontiguousarray(z, float), float(lag), bool(pca)))
