"""A run of compass epochs whose offsets agree with each other, and when such a run proves itself.

The heading filter (:mod:`pdr.heading`) compares each compass epoch's offset δ_m = ψ_true − ψ_g
(compass heading minus gyro heading, :func:`pdr.heading_kernels.close_epochs`) with its state
δ. In a uniform field δ_m stays put whatever the walker does: the compass turns with the gyro.
A field bent by steel gives a δ_m that is also steady while the walker goes straight (the
bend moves with the phone, or the walker stays in the same part of the gradient), but which
moves when the walker turns. So a run of epochs is evidence of the true offset only when

* it agrees with itself: the circular spread ``s = √(−2 ln R̄)`` of its δ_m,
  ``R̄ = |Σ exp(i δ_m)| / n``, stays within ``spread``; and
* it has been tested: it spans a gyro turn of at least ``turn`` (max − min of the unwrapped
  gyro heading at the epochs' ends; a bend that moves with the phone spreads δ_m by up to the
  turn) over at least ``min_s`` seconds, or it has lasted ``long_s`` seconds without one
  (both counted from the end of its first epoch).

:class:`OffsetStreak` keeps the run (O(1) state: sums, not the epochs) and says whether it has
proved itself; an epoch that does not agree with the run starts a new one from itself.
"""
from __future__ import annotations

import math


def held(nu: float, P: float, odd: bool, s) -> bool:
    """Whether the heading filter holds a compass offset ``nu`` (rad) from its δ of variance ``P``
    (settings ``s``: :class:`pdr.heading_settings.HeadingSettings`): when the field is ``odd``
    (strength off the reference by more than ``hold_norm``) and ``|ν| > max(hold_angle,
    hold_sigmas · √P)``. Such an offset is a change the gyro did not see, in a field that is not
    the building's usual one: steel, which bends the field while it still agrees with itself.
    It waits in the filter's rejected run until that run has proved itself. A disagreement in a
    field of the usual strength is not held (a δ that is wrong: the compass corrects it)."""
    return odd and abs(nu) > max(s.hold_angle, s.hold_sigmas * math.sqrt(P))


class OffsetStreak:
    """``add(t_end, dm, psi) -> bool`` (True: the run, with this epoch, has proved itself);
    ``mean`` its circular mean δ_m; ``clear()`` forgets it."""

    def __init__(self, spread: float, turn: float, min_s: float, long_s: float):
        self.spread_max, self.turn, self.min_s, self.long_s = spread, turn, min_s, long_s
        self.clear()

    def clear(self) -> None:
        self.t0 = math.nan  # end of the run's first epoch
        self.c = self.s = 0.0  # Σ cos δ_m, Σ sin δ_m
        self.n = 0
        self.psi_lo, self.psi_hi = math.inf, -math.inf  # range of the gyro heading over the run

    @property
    def mean(self) -> float:
        return math.atan2(self.s, self.c) if self.n else math.nan

    @property
    def spread(self) -> float:
        if not self.n:
            return math.nan
        rho = min(max(math.hypot(self.c, self.s) / self.n, 1e-12), 1.0)
        return math.sqrt(-2.0 * math.log(rho))

    def _start(self, t_end: float, dm: float, psi: float) -> None:
        self.t0, self.c, self.s, self.n = t_end, math.cos(dm), math.sin(dm), 1
        self.psi_lo = self.psi_hi = psi

    def add(self, t_end: float, dm: float, psi: float) -> bool:
        if self.n == 0:
            self._start(t_end, dm, psi)
        else:
            self.c += math.cos(dm)
            self.s += math.sin(dm)
            self.n += 1
            self.psi_lo, self.psi_hi = min(self.psi_lo, psi), max(self.psi_hi, psi)
            if self.spread > self.spread_max:  # not one offset: the run starts again from this epoch
                self._start(t_end, dm, psi)
        return self.proved(t_end, self.long_s)

    def proved(self, t_end: float, long_s: float) -> bool:
        """Has the run, as of the epoch ending at ``t_end``, proved itself: across a turn, or by
        lasting ``long_s`` (the heading's start asks for longer of a run in an odd field)?"""
        span = t_end - self.t0
        turned = self.psi_hi - self.psi_lo >= self.turn and span >= self.min_s
        return turned or span >= long_s
