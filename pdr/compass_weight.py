"""How much one compass measurement counts: its σ_m, and whether its field is odd.

A compass epoch, or a step's own compass heading (:mod:`pdr.heading`), has a circular spread
``s`` of its offsets, a field strength ``|B|`` and an inclination ``I``. Against the field
reference (|B|_ref, I_ref: configured, or learned over the first ``reference_seconds``):

    σ_m² = σ_mag² + s² + (k_n Δ|B|)² + (k_I ΔI)²,

and σ_m = ∞ when ``s`` passes ``spread_gate``, when |B| is not finite, or when Δ|B| / ΔI pass
their gates (only against a *configured* reference: a learned one is the field wherever the
walker stood, so it weighs, never rejects). A learned reference only counts from the end of
its window on (``learned_by``): an earlier measurement is judged as it was when it happened,
so one large batch and many small ones agree.

A measurement at a few per second per responder: these work on Python floats. The squares
are ``x * x`` and the roots correctly rounded, as numpy's elementwise ``x ** 2`` and
``np.sqrt`` compute them, so the bits are those of the array form they replace.
"""
from __future__ import annotations

import math


def measurement_sigma(s, spread: float, nrm: float, inc: float, t: float, ref_norm: float, ref_inc: float,
                      learned_by: float) -> float:
    """σ_m (rad) of a measurement ending at ``t`` (s) with spread ``spread`` (rad), field strength
    ``nrm`` (µT) and inclination ``inc`` (rad); settings ``s``: :class:`pdr.heading_settings.HeadingSettings`."""
    var = s.sigma_mag**2 + spread * spread
    bad = not math.isfinite(spread) or spread > s.spread_gate or not math.isfinite(nrm)
    known = t > learned_by
    for value, ref, configured, weight, gate in ((nrm, ref_norm, s.field_norm, s.norm_weight, s.norm_gate),
                                                 (inc, ref_inc, s.field_inclination, s.inclination_weight,
                                                  s.inclination_gate)):
        if math.isfinite(ref):  # |B| first, then I: the order of the sum
            dev = abs(value - ref) if math.isfinite(configured) or known else 0.0
            w = weight * dev
            var = var + w * w
            if math.isfinite(configured):  # a learned reference is where the walker started: no gate
                bad = bad or dev > gate
    return math.inf if bad else math.sqrt(var)


def odd_field(s, nrm: float, t: float, ref_norm: float, learned_by: float) -> bool:
    """Is the field strength ``nrm`` (µT) at ``t`` more than ``hold_norm`` from the reference
    (configured, or learned once its window is over)? Only such a measurement can be held
    (:func:`pdr.compass_streak.held`). NaN compares false: not odd."""
    return (math.isfinite(s.field_norm) or t > learned_by) and abs(nrm - ref_norm) > s.hold_norm


__all__ = ["measurement_sigma", "odd_field"]
