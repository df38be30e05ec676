"""Madgwick's gradient-descent orientation filter.

S. O. H. Madgwick, "An efficient orientation filter for inertial and inertial/magnetic
sensor arrays", 2010; as used by the smartphone thesis (seed 002, §2.6, eqs. 21-32)::

    q̇ = ½ q ⊗ [0, ω] − β ∇f / |∇f|,      ∇f = J(q)ᵀ f(q)
    f_g = R(q)ᵀ [0, 0, 1] − â                         (gravity, eq. 27 with d = [0,0,1])
    f_b = R(q)ᵀ [b_x, 0, b_z] − m̂,  b from h = q ⊗ m̂ ⊗ q*  (field, distortion compensation)

The IMU path uses ``f_g`` only. Madgwick recommends β = 0.033 (IMU) and 0.041 (MARG)
rad/s; the gyro-bias feedback ("group 2", ζ) is not implemented because its gain was
never published for these sensors and the service estimates gyro bias at standstill.
"""
from __future__ import annotations

import dataclasses

from pdr.ahrs import _kernels
from pdr.ahrs.base import FilterSettings, OrientationFilter


@dataclasses.dataclass(frozen=True)
class MadgwickSettings(FilterSettings):
    # tuned like the others (`firetrack tune ahrs`); Madgwick's own suggestion is 0.041 (MARG)
    beta: float = 0.017  # rad/s, gradient-descent step gain


class Madgwick(OrientationFilter):
    name = "madgwick"
    Settings = MadgwickSettings

    def _kernel(self, q0, dt, acc, gyr, mag, use_mag):
        return _kernels.madgwick_run(q0, dt, acc, gyr, mag, use_mag, self.settings.beta)
