"""Absolute heading evidence for the graph, and how it is kept from making a track worse.

The steps give the graph relative headings (the gyro's turns); nothing in a chain of steps bounds
the heading's drift. Two absolute sources do, each in its own way robust to a disturbed field:

* **Compass** (``ev.mag_heading``, when the PDR judged the field undisturbed): a
  ``PoseRotationPrior2D`` on θ_k under a Cauchy kernel (indoor fields bend by tens of degrees
  near steel, seed 003 §2.2; 40 steps 50° off claiming 5° bend the track ≈3 m with Cauchy,
  ≈18 m with Huber, ≈21 m with plain least squares; tests/test_fusion.py). Before a reading is
  used, :class:`CompassGate` asks whether the compass *turns with the gyro*: the offset
  ``ψ_mag − Σ Δθ`` between the compass and the chain of the steps' turns is constant in a
  uniform field whatever the walker does, while walking through a gradient bends it from metre to
  metre. A window (``mag_window_s``) whose offsets spread more than ``mag_window_gate_rad``
  (circular standard deviation) gives no factor: the disagreement is noticed and the reading
  left out (gating by agreement with the gyro-integrated heading, the issue's third option).
* **The PDR's fused heading** ``ψ_pdr`` (``ev.heading``: its own gyro + compass filter, which
  already rejects disturbed epochs), once per ``pdr_heading_interval_s``, with an error that is
  not white: ``θ_k = ψ_pdr,k + c_k + w`` where c is a slowly wandering offset, an
  Ornstein-Uhlenbeck process with stationary σ_c = ``pdr_heading_sigma_rad`` and correlation
  time τ = ``pdr_heading_time_s``, and w white (``pdr_heading_white_rad``). One variable c per
  factor; between two of them Δt apart the exact discrete OU ``c_j = a·c_i + q``,
  ``a = e^{−Δt/τ}``, is written to first order in Δt/τ as a link ``c_j − c_i ~ N(0, σ_c²·2Δt/τ)``
  and a pull ``c_j ~ N(0, σ_c²·2τ/Δt)`` (their information adds to the OU's). This is the
  "compass bias state that may wander" of issue 12: a segment where the absolute heading is
  steadily off (a bent field over a whole corridor) is absorbed by c instead of bending the
  track, while c cannot run away (σ_c bounds it) so the gyro's drift stays bounded. With
  ``pdr_heading_time_s = None`` the factors are independent priors of σ_c instead.

Why not switchable constraints or GNC: both decide per factor whether it is an outlier, from
its residual; a heading that is off by 10-20° for a minute is not an outlier of any single
factor, it is a bias shared by many, which a state models and a per-factor switch does not.
"""
from __future__ import annotations

import math
from collections import deque

import gtsam
import numpy as np

from pdr.angles import wrap
from service.fusion.keys import C, X
from service.fusion.noise import robust


def heading_offset_factor(pose_key: int, offset_key: int, heading: float, noise) -> gtsam.CustomFactor:
    """``e = wrap(θ − c − ψ)``: the pose's heading θ is a measured heading ψ plus an offset
    variable c (rad). Jacobians: ``∂e/∂ξ = (0, 0, 1)`` (Pose2 retract), ``∂e/∂c = −1``."""

    def error(this, values, jacobians):
        e = wrap(values.atPose2(pose_key).theta() - values.atDouble(offset_key) - heading)
        if jacobians is not None:
            jacobians[0] = np.array([[0.0, 0.0, 1.0]])
            jacobians[1] = np.array([[-1.0]])
        return np.array([e])

    return gtsam.CustomFactor(noise, [pose_key, offset_key], error)


class CompassGate:
    """Does the compass turn with the gyro over the last ``mag_window_s``? (module docstring)"""

    def __init__(self, settings):
        self.s = settings
        self._window: deque[tuple[float, float, float]] = deque()  # (t, cos, sin) of compass − chain offsets
        self.last_spread = math.nan  # rad, circular spread of the window at the last judgement

    def agrees(self, t: float, offset: float) -> bool:
        """Add the offset ``ψ_mag − chain`` (rad) of time ``t``; True when the window's circular
        spread ``√(−2 ln R̄)`` is at most ``mag_window_gate_rad`` (or too few readings to judge)."""
        s = self.s
        w = self._window
        w.append((t, math.cos(offset), math.sin(offset)))
        while w and w[0][0] < t - s.mag_window_s:
            w.popleft()
        if not math.isfinite(s.mag_window_gate_rad) or len(w) < s.mag_window_min_steps:
            return True
        c = sum(x[1] for x in w) / len(w)
        sn = sum(x[2] for x in w) / len(w)
        self.last_spread = math.sqrt(-2.0 * math.log(min(max(math.hypot(c, sn), 1e-12), 1.0)))
        return self.last_spread <= s.mag_window_gate_rad

    def restart(self) -> None:
        """Forget the window (the gyro chain behind its offsets broke: an unknown turn)."""
        self._window.clear()


class HeadingEvidence:
    """Per step, the absolute heading factors on its pose (module docstring)."""

    _broken = False  # (class default: snapshots pickled before it existed)

    def __init__(self, settings):
        self.s = settings
        self.gate = CompassGate(settings)
        self._chain = 0.0  # rad, the gyro's heading chain: the sum of the steps' turns
        self._last_mag_t = -math.inf
        self._last_pdr_t = -math.inf
        self._n_offsets = 0
        self.offset: tuple[int, float] | None = None  # (key, t) of the newest offset variable
        self.offset_value = 0.0  # its latest estimate (the next one starts there)
        self._broken = False  # the PDR heading's error chain broke since the newest offset (add)

    def add(self, ev, turn: float, row: int, graph, values, stamps) -> str | None:
        """Factors for the pose ``row`` made by step ``ev`` with turn ``turn`` (rad). Returns a
        rejection detail when the compass reading was refused for disagreeing with the gyro.

        A step whose turn the PDR does not know (``heading_change_sigma`` not finite: across a gap
        in the samples, a grip jump) breaks both chains that assume one gyro from step to step: the
        compass gate's window starts again (offsets on either side of an unknown turn are not
        comparable), and so does the PDR heading's offset (its error after the break is a new one,
        and the step's own PDR heading, still the one from before the break, gets no factor). A PDR
        heading whose own sigma exceeds ``pdr_heading_max_sigma_rad`` (no compass epoch has passed
        its gates yet) is no absolute evidence either: no factor, and the offset starts again after."""
        s = self.s
        self._chain += turn
        if not (math.isfinite(ev.heading_change) and math.isfinite(ev.heading_change_sigma)):
            self.gate.restart()
            if self.offset is not None:  # not the first step: the PDR heading's chain breaks here
                self._broken = True
                self._last_pdr_t = ev.t  # its next factor one interval on, once its heading has settled
        refused = None
        if math.isfinite(ev.mag_heading) and math.isfinite(ev.mag_heading_sigma) and ev.mag_heading_sigma > 0:
            if not self.gate.agrees(ev.t, wrap(ev.mag_heading - self._chain)):
                refused = f"compass_window: spread {math.degrees(self.gate.last_spread):.1f}°"
            elif ev.t - self._last_mag_t >= s.mag_min_interval_s:
                sigma = max(ev.mag_heading_sigma, s.mag_sigma_floor_rad)
                noise = robust(s.mag_kernel, s.mag_kernel_width, gtsam.noiseModel.Isotropic.Sigma(1, sigma))
                graph.add(gtsam.PoseRotationPrior2D(X(row), gtsam.Rot2(ev.mag_heading), noise))
                self._last_mag_t = ev.t
        if ev.heading_sigma > s.pdr_heading_max_sigma_rad:
            self._broken = True
        elif (s.pdr_heading_interval_s is not None and math.isfinite(ev.heading)
                and ev.t - self._last_pdr_t >= s.pdr_heading_interval_s):
            self._last_pdr_t = ev.t
            if s.pdr_heading_time_s is None:
                noise = robust(s.pdr_heading_kernel, s.mag_kernel_width, gtsam.noiseModel.Isotropic.Sigma(1, s.pdr_heading_sigma_rad))
                graph.add(gtsam.PoseRotationPrior2D(X(row), gtsam.Rot2(ev.heading), noise))
            else:
                self._add_offset(ev, row, graph, values, stamps)
        return refused

    def _add_offset(self, ev, row: int, graph, values, stamps) -> None:
        """θ_k = ψ_pdr,k + c + w with c an Ornstein-Uhlenbeck offset (module docstring)."""
        s = self.s
        sc, tau = s.pdr_heading_sigma_rad, s.pdr_heading_time_s
        key = C(self._n_offsets)
        prev = self.offset
        if prev is not None and prev[1] >= ev.t - s.lag_s + 1.0 and not self._broken:  # the previous offset is still in the window
            dt = ev.t - prev[1]
            values.insert(key, self.offset_value)
            graph.add(gtsam.BetweenFactorDouble(prev[0], key, 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sc * math.sqrt(2.0 * dt / tau))))
            graph.add(gtsam.PriorFactorDouble(key, 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sc * math.sqrt(2.0 * tau / dt))))
        else:  # the first, after a stop longer than the window, or after a break: the stationary prior
            self._broken = False
            values.insert(key, 0.0)
            graph.add(gtsam.PriorFactorDouble(key, 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sc)))
        stamps[key] = float(ev.t)
        noise = robust(s.pdr_heading_kernel, s.mag_kernel_width, gtsam.noiseModel.Isotropic.Sigma(1, s.pdr_heading_white_rad))
        graph.add(heading_offset_factor(X(row), key, ev.heading, noise))
        self._n_offsets += 1
        self.offset = (key, float(ev.t))

    def refresh(self, smoother) -> None:
        """Read the newest offset's estimate back (after an update), to start the next one there."""
        if self.offset is not None:
            self.offset_value = float(smoother.calculateEstimateDouble(self.offset[0]))
