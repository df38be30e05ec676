"""Complementary orientation filter with the smartphone thesis's heading blend.

Seed 002 (CTU smartphone-fusion thesis), §2.4, eqs. 15-16 and 33::

    θ_est = α (θ_est,prev + ω Δt) + (1 − α) θ_compass,      α = τ / (τ + Δt)

Here the gyroscope integrates the full orientation and the blend acts on heading about
the vertical, wrap-safe (the correction is ``(1 − α)·wrap(θ_compass − θ_pred)``, so
359° and 1° are 2° apart, not 358°). The compass is tilt-compensated by the current
estimate. Tilt is corrected towards the accelerometer with its own time constant.
A fixed per-sample ``alpha`` (as in the thesis) can replace ``tau_heading``.
"""
from __future__ import annotations

import dataclasses

from pdr.ahrs import _kernels
from pdr.ahrs.base import FilterSettings, OrientationFilter


@dataclasses.dataclass(frozen=True)
class ComplementarySettings(FilterSettings):
    tau_heading: float = 40.0  # s, time constant of the compass blend (tuned on the Vicon set)
    tau_tilt: float = 2.0  # s, time constant of the accelerometer tilt correction
    alpha: float = 0.0  # fixed per-sample α of eq. 33 when > 0 (overrides tau_heading)


class Complementary(OrientationFilter):
    name = "complementary"
    Settings = ComplementarySettings

    def _kernel(self, q0, dt, acc, gyr, mag, use_mag):
        s = self.settings
        return _kernels.complementary_run(q0, dt, acc, gyr, mag, use_mag, s.tau_tilt, s.tau_heading, s.alpha)
