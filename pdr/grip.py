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

after which the evidence is cleared (the next jump needs ``n`` new steps). The first jump of a
walk needs only ``regrip_steps`` measurements: ω = 0 at the start is a prior, not evidence, and
a phone turned while the walker stood before the first step (IPIN route 21 under the robustness
suite's ``hold_z``: 40 % of the log is standing) has no walking step to compare its tilt with
(below). Between jumps ω
does not follow the noisy measurement, so a walk without a change of grip is not touched;
a turn of the walker leaves the device-relative axis where it was and is not a jump. The
thresholds: a hand-held phone's measurement scatters by about 13° per leg, so ``θ_jump`` = 50°
is far outside that scatter and far below a re-grip's 90°; ``R_min`` = 0.8 is a circular spread
of about 38° (√(−2 ln R)).

A jump is also reported to the heading filter (:mod:`pdr.heading`): the step that carries it
has an unknown turn (its gyro turn is the phone's, not the walker's), so a fusion takes that
step's turn from the absolute heading instead of the gyro. The compass offset δ is left to the
compass: a phone turned in the hand turns the gyro and the field alike, so δ stays right.

**A re-grip seen as it happens.** The jump above needs ``n`` usable steps whose windows all
lie after the change, about 10 s of walking (10 m off by 90° on IPIN trial 03 rep 02 turned
to landscape). But a phone turned in the hand turns about an axis of its own, and unless that
axis is vertical its attitude to gravity changes; a walker's turn is about the vertical and
leaves it alone. Per step ``k`` the levelling's mean attitude ``q_k`` (body -> ENU) gives the
world's up axis in body coordinates, ``u_k = R(q_k)ᵀ e_z``. The reference ``u_r`` is the last
step that was walking (gait phase ρ ≥ ρ_min, σ_z ≤ max) with a settled tilt
(``∠(u_{k−1}, u_k) < θ_settle``) whose next step kept it (``∠(u_k, u_{k+1}) < θ_settle``): a
turn that starts late in a step leaves that step's mean a few degrees turned, within the
settle test, and a reference taken from it shortens θ by as much (and on IPIN trial 05 rep 04
under ``grip_z`` moved the screen normal's elevation past ``regrip_axis_tol``, so the re-grip
was refused). A step that is walking and settled, with

    ∠(u_r, u_k) ≥ θ_tilt

(however long since the reference: a phone turned while the walker stands counts as well)
is a rotation of the device about a non-vertical axis. Before the first walking step there is
no such reference, so the samples before that step's own, within its window (``window`` s, as
far back as every batching keeps), stand in for it: the mean up axis of their leading run
that stays within ``θ_settle`` of the first one, when that run has ``standing_samples`` and
σ_z ≤ ``standing_vertical_std`` (:func:`standing_up`), the attitude the walker stood in
(looked for at every walking step until there is a reference, and used only within ``window``
s of the step it came from: one from long before, a wave or a pause, is no reference). A
phone turned 1.5 s before the walk (IPIN route 21 rep 03 under ``hold_z``) is caught at the
second walking step instead of the seventh (6.6 s later); one turned earlier leaves no
standing sample of the old grip in reach, and the fast first jump of the walking axis (above)
catches it.

A re-grip turns the phone about one of its own axes ``a`` (the screen normal: portrait to
landscape; x: the screen raised; y: rolled), so ``u_k = R(a, θ)ᵀ u_r``: ``a`` is the body axis whose elevation kept (within
``regrip_axis_tol``), and θ is where ``u`` moved around it (the signed angle β from ``u_r``'s
part across ``a`` to ``u_k``'s, θ = −β). The device's attitude without the re-grip is
``q_k ⊗ q(a, θ)*`` (the walker's turn in between, about the vertical, is in both), so

    ω ← wrap(ω − (yaw(q_k) − yaw(q_k ⊗ q(a, θ)*)))   (0 if within ``snap`` of 0),

with ``yaw`` the device heading vector's (:func:`pdr.heading_kernels.level_and_compass`). Only a
turn about the screen normal ``z`` acts: a pitch (about ``x``) is kept by the heading vector,
a roll (about ``y``) leaves the forward axis, and a change no single axis explains is left to
the walking axis (acting on them broke 4 walks of ``hold_x``, the screen raised by 60°, while
the phone stood past vertical). After a jump older evidence is dropped, windows reaching back
before it are not used, and the next jump needs only ``regrip_steps`` measurements: the
walking axis confirms ω or corrects it. A phone lying flat
turned about its vertical screen normal keeps its tilt: only the ordinary jump sees that.

Limits: a phone turned by 180° about its screen normal (reversed) keeps its axis; only the
gait's phase tells, and on stairs that phase turns round while the grip does not (trial 52 of
the IPIN set: 20 steps at 130-170°), so a reversal alone is not a jump here.
"""
from __future__ import annotations

import dataclasses
import math
from collections import deque

import numpy as np

from pdr import quaternion as quat
from pdr.angles import wrap
from pdr.fixed_order import mean0, row_dot


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
    regrip_tilt: float = math.radians(25.0)  # θ_tilt, rad: a change of tilt between settled walking steps that is a re-grip
    regrip_settle: float = math.radians(10.0)  # θ_settle, rad: the tilt has settled (last step to this one)
    snap: float = math.radians(30.0)  # rad, a predicted ω this close to 0 is the texting grip again
    regrip_steps: int = 4  # measurements that must agree for a jump after a change of tilt
    regrip_axis_tol: float = math.radians(15.0)  # rad: the turn's axis kept its elevation within this (a walker's hold wobbles by 5-10°)
    regrip_lever: float = math.sin(math.radians(20.0))  # up's part across the axis, at least (else θ is ill-conditioned)
    standing_samples: int = 10  # samples before the first walking step's own that make a standing attitude, at least
    standing_vertical_std: float = 0.5  # m/s², σ_z of those samples at most: the walker stood (walking: 0.6-1.3)


class GripTracker:
    """``step(axis) -> (ω, jumped)`` once per step, in step order (``axis`` a
    :class:`pdr.walking_direction.WalkingAxis`)."""

    def __init__(self, settings: GripSettings | None = None):
        self.settings = settings or GripSettings()
        self.offset = 0.0  # ω, rad
        self.jumps = 0
        self.regrips = 0  # jumps of ω from the tilt (counted in ``jumps`` too)
        self._recent: deque = deque(maxlen=self.settings.steps)
        self._prev_up = None  # the last step's up axis in body coordinates
        self._ref = None  # (t, up) of the last confirmed walking step (module docstring): the attitude before a re-grip
        self._cand = None  # (t, up) of the last step if walking with a settled tilt: the reference once the next step keeps it
        self._standing = None  # (t, up) of the walker standing just before the first walking step: the first reference
        self._since = -math.inf  # time of the last re-grip: windows reaching before it are not evidence
        self._fast = True  # at the start (ω = 0 is a prior, not evidence) and after a change of tilt:
        # a jump needs only regrip_steps measurements

    def usable(self, m) -> bool:
        s = self.settings
        return (math.isfinite(m.angle) and m.anisotropy >= s.min_anisotropy and m.phase >= s.min_phase
                and m.vertical_std <= s.max_vertical_std)

    def walking(self, m) -> bool:
        """The window looks like walking (the gait's phase shows, σ_z in range), whatever its axis."""
        s = self.settings
        return m.phase >= s.min_phase and m.vertical_std <= s.max_vertical_std

    @property
    def wants_standing(self) -> bool:
        """No reference yet: the samples before the next step's own may give one (:meth:`step`'s ``before``)."""
        return self.settings.enabled and self._ref is None

    def step(self, m, t: float = math.nan, q=None, yaw_of=None, before=None) -> tuple[float, bool]:
        """ω after a step at ``t`` (s) with measurement ``m`` and attitude ``q`` (body -> ENU,
        scalar first); ``yaw_of(q (n, 4))`` the device heading's yaw of attitudes. Without
        ``q`` the walking axis alone decides. ``before``: ``(q (n, 4), z (n,))``, the attitudes
        and vertical specific force of the samples just before this step's own, when
        :attr:`wants_standing` (:func:`standing_up`)."""
        s = self.settings
        if not s.enabled:
            return self.offset, False
        if before is not None and self.wants_standing and self.walking(m) and math.isfinite(t):
            up = standing_up(*before, s)
            if up is not None:
                self._standing = (t, up)
        if q is not None and yaw_of is not None and self._regrip(m, t, q, yaw_of):
            return self.offset, True
        if not self.usable(m) or t - s.window < self._since:
            return self.offset, False
        a = m.angle
        self._recent.append((math.cos(2.0 * a), math.sin(2.0 * a), math.cos(a), math.sin(a)))
        if len(self._recent) >= s.steps:
            self._fast = False  # the ordinary count is there: no more need to hurry
        n = s.regrip_steps if self._fast else s.steps
        if len(self._recent) < n:
            return self.offset, False
        recent = list(self._recent)[-n:]
        c2 = sum(v[0] for v in recent) / n
        s2 = sum(v[1] for v in recent) / n
        if math.hypot(c2, s2) < s.consistency:
            return self.offset, False
        axis = 0.5 * math.atan2(s2, c2)  # the walking axis, modulo π
        same = min(abs(float(wrap(axis - self.offset))), abs(float(wrap(axis + math.pi - self.offset))))
        if same < s.jump:  # the same grip: ω follows its axis on the side it is on (0 while texting)
            if abs(float(wrap(self.offset))) < 1e-12 and abs(float(wrap(axis))) < s.jump:
                return self.offset, False
            near = _nearest(axis, self.offset)
            self.offset = 0.0 if abs(near) < s.snap else near  # back within snap of forward: the texting grip
            return self.offset, False
        # a new grip: the side from the gait's phase (the signed measurements' mean direction)
        mean = math.atan2(sum(v[3] for v in recent), sum(v[2] for v in recent))
        target = _nearest(axis, mean)
        self.offset = 0.0 if abs(float(wrap(target))) < s.jump else target
        self.jumps += 1
        self._recent.clear()
        self._fast = False
        return self.offset, True


    def _regrip(self, m, t: float, q, yaw_of) -> bool:
        """The re-grip test of the module docstring; True when ω jumped."""
        s = self.settings
        q = np.asarray(q, float)
        if not (math.isfinite(t) and np.all(np.isfinite(q))):
            return False
        u = _up(q)
        prev, self._prev_up = self._prev_up, u
        cand, self._cand = self._cand, None
        if not self.walking(m) or prev is None or _angle(prev, u) >= s.regrip_settle:
            return False  # not walking, or the tilt still moving: the reference stays where it was
        ref = self._ref
        if ref is None and self._standing is not None and t - self._standing[0] <= s.window:
            ref = self._standing  # only while fresh: an older one may be from a wave or a pause long before the walk
        if cand is not None:  # the last step kept its tilt into this one: it is the reference from now on
            self._ref = cand
        self._cand = (t, u)
        if ref is None or _angle(ref[1], u) < s.regrip_tilt:
            return False
        self._ref, self._cand = (t, u), None  # the tilt changed: the new attitude is the reference
        turn = self._grip_turn(ref[1], u)
        if turn is None or turn[0][2] != 1.0:  # only a turn about the screen normal moves the forward axis
            return False  # sideways: a pitch is kept by the heading vector, a roll keeps y; else the axis tells
        q_before = quat.multiply(q, quat.conjugate(quat.from_axis_angle(*turn)))  # the walker's attitude, no re-grip
        y = yaw_of(np.array([q, q_before]))
        omega = float(wrap(self.offset - float(wrap(y[0] - y[1]))))
        omega = 0.0 if abs(omega) < s.snap else omega
        if abs(float(wrap(omega - self.offset))) < s.snap:  # a turn that leaves the heading (a pitch): nothing to do
            return False
        self._suspect(t)
        self.offset = omega
        self.jumps += 1
        self.regrips += 1
        return True

    def _grip_turn(self, u0, u1):
        """``(axis, θ)`` of a turn about one of the body axes that takes the body-frame up axis
        ``u0`` to ``u1`` (``u1 = R(axis, θ)ᵀ u0``), or None: the axis is the one whose elevation
        kept within ``regrip_axis_tol``, θ from where up moved around it."""
        s = self.settings
        best = None
        for a in np.eye(3):
            a0, a1 = _dot(u0, a), _dot(u1, a)
            keep = abs(math.asin(min(max(a0, -1.0), 1.0)) - math.asin(min(max(a1, -1.0), 1.0)))
            p0, p1 = u0 - a0 * a, u1 - a1 * a
            if keep <= s.regrip_axis_tol and min(_norm(p0), _norm(p1)) >= s.regrip_lever:
                if best is None or keep < best[0]:
                    beta = math.atan2(_dot(a, np.cross(p0, p1)), _dot(p0, p1))
                    best = (keep, a, -beta)
        return None if best is None else (best[1], best[2])

    def _suspect(self, since: float) -> None:
        """The grip may have changed at ``since``: older evidence is dropped, windows reaching
        before it are not evidence, and the next jump needs only ``regrip_steps`` measurements."""
        self._recent.clear()
        self._since = since
        self._fast = True


def standing_up(q, z, settings: GripSettings) -> np.ndarray | None:
    """The world's up axis in body coordinates while the walker stood, from attitudes ``q``
    (n, 4) and vertical specific force ``z`` (n,) of the samples before the first walking step,
    oldest first: the mean up axis of the leading run of samples whose up axis stays within
    ``regrip_settle`` of the first one's (the attitude held before any turn among them), or
    None unless that run has ``standing_samples`` with σ_z ≤ ``standing_vertical_std``."""
    q = np.asarray(q, float)
    z = np.asarray(z, float)
    if len(q) < settings.standing_samples or not (np.all(np.isfinite(q)) and np.all(np.isfinite(z))):
        return None
    ups = _ups(q)
    first = ups[0]
    # ∠(u_0, u_i) = acos(u_0 · u_i): the dot products as arrays (each the same bits as _dot),
    # the acos per sample in math's own (numpy's may take a CPU-specific kernel)
    n = _settled_run(np.clip(row_dot(ups, first), -1.0, 1.0), settings.regrip_settle)
    zs = z[:n] - mean0(z[:n])
    if n < settings.standing_samples or math.sqrt(_sum_squares(zs) / n) > settings.standing_vertical_std:
        return None
    mean = mean0(ups[:n])
    return mean / _norm(mean)


def _settled_run(cosines: np.ndarray, settle: float) -> int:
    """The first i ≥ 1 with ``math.acos(cosines[i]) ≥ settle`` (else their number). numpy's
    arccos may differ from math's in the last bit, so it only rules samples out, far from the
    bound: ``acos(c) ≥ settle`` needs ``c ≤ cos(settle)``, and 1e-9 of c is about 6e-9 rad at 10°
    (the acos' slope, 1/sin), millions of ulps. Each sample left is judged by ``math.acos``."""
    for i in (np.flatnonzero(cosines[1:] <= math.cos(settle) + 1e-9) + 1).tolist():
        if math.acos(float(cosines[i])) >= settle:
            return i
    return len(cosines)


def _sum_squares(v: np.ndarray) -> float:
    """Σ v_i² summed left to right from v_0² (:func:`_dot` of ``v`` with itself, the same bits):
    a running sum (``np.cumsum``, add.accumulate) adds one term at a time in order."""
    return float(np.cumsum(v * v)[-1]) if len(v) else 0.0


def _up(q) -> np.ndarray:
    """The world's up axis in body coordinates, ``R(q)ᵀ e_z`` (the third row of R); in Python
    floats (the same IEEE operations as numpy's scalars, a third of the time)."""
    w, x, y, z = np.asarray(q, float).tolist()
    return np.array([2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)])


def _ups(q: np.ndarray) -> np.ndarray:
    """:func:`_up` of every row of ``q`` (n, 4): (n, 3), elementwise, so row i has the same bits as ``_up(q[i])``."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    out = np.empty((len(q), 3))
    out[:, 0] = 2.0 * (x * z - w * y)
    out[:, 1] = 2.0 * (y * z + w * x)
    out[:, 2] = 1.0 - 2.0 * (x * x + y * y)
    return out


def _angle(a, b) -> float:
    """Angle between unit vectors (rad)."""
    return math.acos(min(max(_dot(a, b), -1.0), 1.0))


def _dot(a, b) -> float:
    """a · b summed left to right (``pdr.fixed_order``: no BLAS, the same bits on every CPU), in
    Python floats: the same IEEE products and sums, one at a time, as :func:`row_dot`'s."""
    x, y = np.asarray(a, float).tolist(), np.asarray(b, float).tolist()
    if len(x) != len(y):
        raise ValueError(f"_dot: {len(x)} against {len(y)} terms")
    if not x:
        return 0.0
    acc = x[0] * y[0]
    for u, v in zip(x[1:], y[1:]):
        acc = acc + u * v
    return acc


def _norm(a) -> float:
    """‖a‖ = √(a · a), in the fixed order of :func:`_dot`."""
    return math.sqrt(_dot(a, a))


def _nearest(axis: float, ref: float) -> float:
    """``axis`` or ``axis + π``, whichever is closer to ``ref`` (wrapped to (−π, π])."""
    a = float(wrap(axis))
    b = float(wrap(axis + math.pi))
    return a if abs(float(wrap(a - ref))) <= abs(float(wrap(b - ref))) else b
