"""Changes of grip: when the phone's attitude to the walking direction changes, notice it.

The heading of travel is the device's heading plus an offset ``ω`` (walking direction − the
device's forward axis, CCW). A walker who texts holds ``ω ≈ 0``, and assuming so is more
accurate than measuring it (:mod:`pdr.walking_direction`: per-leg error 10° against 13°).
But a phone turned in the hand (portrait to landscape), put in a pocket or swung changes
``ω`` at once, and nothing in the gyro or the compass can tell: the gyro sees the phone turn
and the compass agrees with it, while the walker goes straight on.

The walk itself tells. Per step ``k`` the principal axis of the horizontal specific force over
the last ``window`` seconds, signed by the gait's phase (:func:`pdr.walking_direction.walking_angle`),
measures the offset: ``m_k`` (rad) with anisotropy ``e_k`` (how clearly the swing has an axis).
The offset ``ω`` is a **jump state**: it holds its value (0 at the start) until the evidence of
the last ``n`` steps with ``e_k ≥ e_min`` agrees on another value,

    μ = arg Σ exp(i m_j),   R = |Σ exp(i m_j)| / n,
    jump when  R ≥ R_min  and  |wrap(μ − ω)| ≥ θ_jump:   ω ← μ,

after which the evidence is cleared (the next jump needs ``n`` new steps). Between jumps ω
does not follow the noisy measurement, so a walk without a change of grip is not touched;
a turn of the walker leaves the device-relative axis where it was and is not a jump. The
thresholds: a hand-held phone's measurement scatters by about 13° per leg, so ``θ_jump`` = 50°
is far outside that scatter and far below a re-grip's 90°; ``R_min`` = 0.8 is a circular spread
of about 38° (√(−2 ln R)).

A jump is also reported to the heading filter (:mod:`pdr.heading`): the step that carries it
has an unknown turn (its gyro turn is the phone's, not the walker's), so a fusion takes that
step's turn from the absolute heading instead of the gyro. The compass offset δ is left to the
compass: a phone turned in the hand turns the gyro and the field alike, so δ stays right.

Limits: a phone turned by 180° about its screen normal (reversed) keeps its axis; only the
gait's phase tells, and on stairs that phase turns round while the grip does not (trial 52 of
the IPIN set: 20 steps at 130-170°), so a reversal alone is not a jump here.
"""
from __future__ import annotations

import dataclasses
import math
from collections import deque

from pdr.angles import wrap


@dataclasses.dataclass(frozen=True)
class GripSettings:
    enabled: bool = True
    window: float = 3.0  # s of samples per measurement (about five steps; at most 4 max_step_duration)
    lag: float = 0.125  # s, the phase test's lag (about a quarter step)
    steps: int = 8  # n, measurements that must agree before a jump
    min_anisotropy: float = 0.3  # e_min: a weaker horizontal axis is not a measurement
    min_phase: float = 0.35  # ρ_min: the gait's phase must show (not a waved or tapped phone)
    max_vertical_std: float = 2.5  # m/s², σ_z above this is not walking (a calibration wave: 3-7)
    consistency: float = 0.8  # R_min, mean resultant length of the n doubled angles
    jump: float = math.radians(50.0)  # θ_jump, rad


class GripTracker:
    """``step(axis) -> (ω, jumped)`` once per step, in step order (``axis`` a
    :class:`pdr.walking_direction.WalkingAxis`)."""

    def __init__(self, settings: GripSettings | None = None):
        self.settings = settings or GripSettings()
        self.offset = 0.0  # ω, rad
        self.jumps = 0
        self._recent: deque = deque(maxlen=self.settings.steps)

    def usable(self, m) -> bool:
        s = self.settings
        return (math.isfinite(m.angle) and m.anisotropy >= s.min_anisotropy and m.phase >= s.min_phase
                and m.vertical_std <= s.max_vertical_std)

    def step(self, m) -> tuple[float, bool]:
        s = self.settings
        if not s.enabled or not self.usable(m):
            return self.offset, False
        a = m.angle
        self._recent.append((math.cos(2.0 * a), math.sin(2.0 * a), math.cos(a), math.sin(a)))
        if len(self._recent) < s.steps:
            return self.offset, False
        c2 = sum(v[0] for v in self._recent) / s.steps
        s2 = sum(v[1] for v in self._recent) / s.steps
        if math.hypot(c2, s2) < s.consistency:
            return self.offset, False
        axis = 0.5 * math.atan2(s2, c2)  # the walking axis, modulo π
        same = min(abs(float(wrap(axis - self.offset))), abs(float(wrap(axis + math.pi - self.offset))))
        if same < s.jump:  # the same grip: ω follows its axis on the side it is on (0 while texting)
            if abs(float(wrap(self.offset))) < 1e-12 and abs(float(wrap(axis))) < s.jump:
                return self.offset, False
            self.offset = _nearest(axis, self.offset)
            return self.offset, False
        # a new grip: the side from the gait's phase (the signed measurements' mean direction)
        mean = math.atan2(sum(v[3] for v in self._recent), sum(v[2] for v in self._recent))
        target = _nearest(axis, mean)
        self.offset = 0.0 if abs(float(wrap(target))) < s.jump else target
        self.jumps += 1
        self._recent.clear()
        return self.offset, True


def _nearest(axis: float, ref: float) -> float:
    """``axis`` or ``axis + π``, whichever is closer to ``ref`` (wrapped to (−π, π])."""
    a = float(wrap(axis))
    b = float(wrap(axis + math.pi))
    return a if abs(float(wrap(a - ref))) <= abs(float(wrap(b - ref))) else b
