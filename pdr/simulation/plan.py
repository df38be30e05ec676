"""A walker's plan: route legs turned into path rows and time rows, one leg at a time.

The rows are the tables :func:`pdr.simulation.motion.evaluate` reads (see there for their
equations). Planning is Python on scalars, once per leg (every few seconds of walking); the
samples are never touched here.

A leg runs from one waypoint to the next:

* the path is a line, shortened at each end by a corner taken while walking (a smooth
  curve of ``turn_s_per_rad`` seconds per radian, at most 45 % of either adjacent leg);
  a corner sharper than ``max_walking_turn_rad``, a pause, the route's end or a degenerate
  leg is a *stop* instead: slow down, turn on the spot (``spin_s_per_rad``), stand, start;
* a leg that changes floor is a flight of stairs along its line: one step per
  ``stairs_riser_m`` of height (the tread is whatever the horizontal run gives; random routes
  make it ``stairs_tread_m``) at ``stairs_cadence_factor`` times the walker's cadence; corners
  at its ends stay level;
* the step lengths of a leg are scaled (by about 1/2N at most) so that it is a whole number
  N of steps: every waypoint, and so every stop, falls on a whole step, and the true step
  count ``floor(φ)`` matches what was walked. Walking on through a waypoint, the step length
  changes linearly over the next step and the cadence over ``cadence_blend_s``, so the
  speed never jumps;
* time rows: a start ramp after a stop (or a cadence blend), a cruise, a stop ramp before a
  stop (``ramp_s`` each, shortened on legs too short for both), then the stop's turn and
  pause.

The same generator (``rng``) draws random waypoints and the per-leg cadence in a fixed
order, so the plan does not depend on when, or in what batches, it is asked for.
Interruptions (:meth:`WalkerPlan.stand_still`, :meth:`WalkerPlan.collapse`) edit rows that
lie in the future only.
"""
from __future__ import annotations

import bisect
import dataclasses
import math
from collections import deque
from collections.abc import Iterator

import numpy as np

from pdr.angles import wrap
from pdr.simulation.motion import (
    NPC,
    NSEG,
    PC_PHI0,
    SEG_DP,
    SEG_DR,
    SEG_DY,
    SEG_EA,
    SEG_EB,
    SEG_F,
    SEG_HI,
    SEG_LO,
    SEG_P0,
    SEG_PHI0,
    SEG_R0,
    SEG_T0,
    SEG_T1,
    SEG_TA,
    SEG_TO,
    SEG_TR,
    SEG_Y0,
    corner_cut,
    phase_profile,
    smooth_step,
    sway_at,
)
from pdr.simulation.settings import (
    Route,
    WalkerSettings,
    random_start,
    random_waypoints,
)
from pdr.simulation.strides import WalkerTraits, solve_scale, step_layout


def _stopping(r) -> bool:
    """A time row that slows to a standstill (its envelope ends at zero)."""
    return r[SEG_F] > 0.0 and abs(r[SEG_EA] - r[SEG_EB]) < 1e-12


@dataclasses.dataclass(frozen=True)
class PlanState:
    """The plan evaluated at one time: row index, phase, envelope, gait scale (step rate over the
    walker's cadence), yaw/pitch/roll offsets of the row, path row id."""

    row: int
    phi: float
    e: float
    g: float
    yaw: float
    pitch: float
    roll: float
    piece: int


class WalkerPlan:
    """Rows of one walker, planned lazily; old rows are forgotten by :meth:`window`."""

    def __init__(self, settings: WalkerSettings, traits: WalkerTraits, rng: np.random.Generator,
                 route: Route | None, start_t: float, bounds, floors):
        self.s = settings
        self.traits = traits
        self._rng = rng
        self.rows: list[list[float]] = []
        self.pieces: list[list[float]] = []
        self.piece_base = 0  # id of pieces[0]
        self.finished = False
        self.version = 0  # bumped when future rows are edited
        if route is not None:
            x, y = (float(v) for v in route.waypoints[0])
            floor, first_pause = int(route.floors[0]), float(route.pauses[0])
            self._source: Iterator = iter([(float(p[0]), float(p[1]), int(f), float(w))
                                           for p, f, w in zip(route.waypoints[1:], route.floors[1:], route.pauses[1:])])
            heading = 0.0
        else:
            x, y, floor, heading = random_start(rng, bounds, floors)
            first_pause = 0.0
            self._source = random_waypoints(rng, bounds, floors, settings, (x, y, floor), heading)
        self._queue: deque = deque()
        # state at the end of the plan
        self.t_end = float(start_t)
        self.phi = 0.0
        self.x, self.y, self.z = x, y, floor * settings.floor_height_m
        q = self._peek(1)
        if q and math.hypot(q[0][0] - x, q[0][1] - y) > 1e-6:
            heading = math.atan2(q[0][1] - y, q[0][0] - x)
        self.path_heading = heading
        self.yaw_offset = 0.0
        self.stopped = True
        self.pending_pause = settings.initial_still_s + first_pause
        self._curve: tuple | None = None  # corner whose second half starts the next leg
        self.lam_end = traits.step_length_m  # step length (m) and cadence (Hz) at the end of the plan
        self.f_end = traits.cadence_hz
        self._add_piece(0.0, 0.0, 0.0, 0.0, 0.0, x, y, heading, 0.0, 1.0, self.z)  # where the walker stands

    # -- rows -------------------------------------------------------------------------------
    def _add_piece(self, phi0, lam, g, w, u0, x0, y0, psi0, dpsi, ls, z0, dz=0.0, steps=0.0) -> int:
        """A path row; one climbing ``dz`` over its ``steps`` steps eases in and out over one step
        (at most a quarter of the flight)."""
        ease = min(1.0, 0.25 * steps) if dz else 0.0
        k = dz / (steps - ease) if dz else 0.0
        self.pieces.append([phi0, lam, g, w, u0, x0, y0, psi0, math.cos(psi0), math.sin(psi0), dpsi, ls, z0, k,
                            steps, ease])
        return self.piece_base + len(self.pieces) - 1

    @property
    def last_piece(self) -> int:
        return self.piece_base + len(self.pieces) - 1

    @staticmethod
    def _row(t0, t1, phi0, f=0.0, ea=0.0, eb=0.0, tr=1.0, y0=0.0, dy=0.0, p0=0.0, dp=0.0, r0=0.0, dr=0.0,
             ta=1.0, lo=0, hi=0):
        r = [0.0] * NSEG
        r[SEG_T0], r[SEG_T1], r[SEG_TO], r[SEG_PHI0], r[SEG_F] = t0, t1, t0, phi0, f
        r[SEG_EA], r[SEG_EB], r[SEG_TR], r[SEG_Y0], r[SEG_DY] = ea, eb, tr, y0, dy
        r[SEG_P0], r[SEG_DP], r[SEG_R0], r[SEG_DR] = p0, dp, r0, dr
        r[SEG_TA], r[SEG_LO], r[SEG_HI] = ta, float(lo), float(hi)
        return r

    def _stand(self, seconds: float, y0: float, dy: float = 0.0) -> None:
        """Stand (turning by ``dy`` on the spot, if any) at the end of the plan."""
        t0 = self.t_end
        ta = seconds if (dy != 0.0 and math.isfinite(seconds)) else 1.0
        p = self.last_piece
        self.rows.append(self._row(t0, t0 + seconds, self.phi, y0=y0, dy=dy, ta=ta, lo=p, hi=p))
        self.t_end = t0 + seconds

    # -- waypoints ----------------------------------------------------------------------------
    def _peek(self, n: int) -> deque:
        while len(self._queue) < n:
            nxt = next(self._source, None)
            if nxt is None:
                break
            self._queue.append(nxt)
        return self._queue

    # -- planning -------------------------------------------------------------------------------
    def extend(self, until: float) -> None:
        """Plan legs until the rows reach past time ``until``."""
        while not self.finished and self.t_end <= until:
            self._plan_leg()

    def _plan_leg(self) -> None:
        s, tr = self.s, self.traits
        q = self._peek(2)
        if not q:  # the route has ended: stand for good
            if self.pending_pause > 0:
                self._stand(self.pending_pause, self.yaw_offset)
            self._stand(math.inf, self.yaw_offset)
            self.finished = True
            return
        ax, ay, afloor, apause = q[0]
        az = afloor * s.floor_height_m
        length = math.hypot(ax - self.x, ay - self.y)
        if length < 1e-6:  # a waypoint where the walker already is: only its pause counts
            q.popleft()
            self.pending_pause += apause
            return
        psi = math.atan2(ay - self.y, ax - self.x)
        if self.stopped:  # turn on the spot towards the leg, then stand out the pause
            spin = wrap(psi - self.path_heading - self.yaw_offset)
            if abs(spin) > 1e-9:
                self._stand(max(s.spin_min_s, abs(spin) * s.spin_s_per_rad), self.yaw_offset, spin)
                self.yaw_offset += spin
            if self.pending_pause > 0:
                self._stand(self.pending_pause, self.yaw_offset)
                self.pending_pause = 0.0

        d_start = self._curve[5] if self._curve else 0.0
        nxt = q[1] if len(q) > 1 else None
        stop_end = apause > 0 or nxt is None
        curve = None
        turn = 0.0
        if not stop_end:
            lb = math.hypot(nxt[0] - ax, nxt[1] - ay)
            turn = wrap(math.atan2(nxt[1] - ay, nxt[0] - ax) - psi) if lb >= 1e-6 else 0.0
            if lb < 1e-6 or abs(turn) > s.max_walking_turn_rad:
                stop_end = True
            elif abs(turn) > 1e-9:
                ls = min(max(abs(turn) * s.turn_s_per_rad, s.turn_min_s), s.turn_max_s) * tr.step_length_m * tr.cadence_hz
                d1 = corner_cut(turn)
                ls = min(ls, 0.45 * min(length - d_start, lb) / d1)
                d = d1 * ls
                curve = (ax - d * math.cos(psi), ay - d * math.sin(psi), psi, turn, ls, d)

        # path rows: [second half of the last corner] [line, maybe stairs] [first half of the next corner]
        stairs = abs(az - self.z) > 1e-9
        flat = tr.step_length_m
        parts = []  # (length, nominal m per step, u0, x0, y0, psi0, dpsi, ls, z0, dz)
        if self._curve:
            cx, cy, cpsi, cturn, cls, _ = self._curve
            parts.append((0.5 * cls, flat, 0.5 * cls, cx, cy, cpsi, cturn, cls, self.z, 0.0))
        d_end = curve[5] if curve else 0.0
        line = length - d_start - d_end
        c, sn = math.cos(psi), math.sin(psi)
        # a flight of stairs takes one step per riser, whatever its horizontal run
        tread = line * s.stairs_riser_m / abs(az - self.z) if stairs else flat
        parts.append((line, tread, 0.0, self.x + d_start * c, self.y + d_start * sn,
                      psi, 0.0, line, self.z, az - self.z))
        if curve:
            parts.append((0.5 * curve[4], flat, 0.0, curve[0], curve[1], psi, turn, curve[4], az, 0.0))
        parts = [p for p in parts if p[0] > 1e-9]
        lam_in = None if self.stopped else self.lam_end
        n_steps = max(1, round(sum(c for *_, c in step_layout(parts, 1.0, lam_in))))
        layout = step_layout(parts, solve_scale(parts, lam_in, n_steps), lam_in)
        phi = self.phi
        ids = []
        for (length_i, lam, u0, x0, y0, psi0, dpsi, ls, z0, dz), (lam0, g, w, cyc) in zip(parts, layout):
            ids.append(self._add_piece(phi, lam0, g, w, u0, x0, y0, psi0, dpsi, ls, z0, dz, cyc))
            phi += cyc
        first, last = ids[0], ids[-1]

        # time rows: [start ramp | cadence blend] [cruise] [stop ramp]
        f = tr.cadence_hz * float(np.clip(1.0 + s.cadence_leg_jitter * self._rng.standard_normal(), 0.7, 1.3))
        if stairs:
            f *= s.stairs_cadence_factor
        t_up = s.ramp_s if self.stopped else 0.0
        t_dn = s.ramp_s if stop_end else 0.0
        c_up, c_dn = 0.5 * f * t_up, 0.5 * f * t_dn
        if c_up + c_dn > n_steps:
            k = n_steps / (c_up + c_dn)
            t_up, t_dn, c_up, c_dn = t_up * k, t_dn * k, c_up * k, c_dn * k
        e_in, t_bl, c_bl = 1.0, 0.0, 0.0
        if not self.stopped and abs(self.f_end - f) > 1e-12:  # walked through: blend the cadence
            e_in = self.f_end / f
            t_bl = s.cadence_blend_s
            c_bl = 0.5 * f * t_bl * (e_in + 1.0)
            if c_bl > 0.5 * (n_steps - c_dn):
                t_bl *= 0.5 * (n_steps - c_dn) / c_bl
                c_bl = 0.5 * (n_steps - c_dn)
        t, phi0, phi_end = self.t_end, self.phi, self.phi + n_steps
        if t_up > 0:
            self.rows.append(self._row(t, t + t_up, phi0, f, 0.5, -0.5, t_up, lo=first, hi=last))
            t += t_up
        if t_bl > 0:
            self.rows.append(self._row(t, t + t_bl, phi0, f, 0.5 * (e_in + 1.0), 0.5 * (e_in - 1.0), t_bl, lo=first, hi=last))
            t += t_bl
        cruise = n_steps - c_up - c_bl - c_dn
        if cruise > 1e-9:
            self.rows.append(self._row(t, t + cruise / f, phi0 + c_up + c_bl, f, 1.0, 0.0, lo=first, hi=last))
            t += cruise / f
        if t_dn > 0:
            self.rows.append(self._row(t, t + t_dn, phi_end - c_dn, f, 0.5, 0.5, t_dn, lo=first, hi=last))
            t += t_dn
        self.lam_end, self.f_end = layout[-1][0] + layout[-1][1] * layout[-1][2], f
        self.t_end, self.phi = t, phi_end
        self.x, self.y, self.z = ax, ay, az
        q.popleft()
        self.stopped = stop_end
        self._curve = curve
        self.yaw_offset = 0.0
        self.path_heading = psi + 0.5 * turn if curve else psi
        if stop_end:
            self.pending_pause = apause

    # -- looking things up ------------------------------------------------------------------
    def row_index(self, t: float) -> int:
        i = bisect.bisect_right([r[SEG_T0] for r in self.rows], t) - 1
        if i < 0:
            raise ValueError(f"time {t} lies before the plan's first kept row ({self.rows[0][SEG_T0]})")
        return i

    def piece_for(self, phi: float, lo: int, hi: int) -> int:
        """The last path row in ``lo..hi`` that starts at or before phase ``phi`` (else ``lo``)."""
        for pid in range(min(hi, self.last_piece), lo, -1):
            if self.pieces[pid - self.piece_base][PC_PHI0] <= phi:
                return pid
        return lo

    def state_at(self, t: float) -> PlanState:
        i = self.row_index(t)
        r = self.rows[i]
        tau = t - r[SEG_TO]
        phi, e, _ = phase_profile(tau, r[SEG_PHI0], r[SEG_F], r[SEG_EA], r[SEG_EB], r[SEG_TR])
        S = float(smooth_step(tau / r[SEG_TA])[0]) if (r[SEG_DY] or r[SEG_DP] or r[SEG_DR]) else 0.0
        phi = float(phi)
        e = float(e) if r[SEG_F] else 0.0
        pid = self.piece_for(phi, int(r[SEG_LO]), int(r[SEG_HI]))
        return PlanState(i, phi, e, r[SEG_F] * e / self.traits.cadence_hz, r[SEG_Y0] + r[SEG_DY] * S,
                         r[SEG_P0] + r[SEG_DP] * S, r[SEG_R0] + r[SEG_DR] * S, pid)

    def _time_of_phase(self, r: list[float], phi: float) -> float:
        """When row ``r`` reaches phase ``phi`` (closed form while cruising, else bisection)."""
        if r[SEG_EB] == 0.0:
            return r[SEG_TO] + (phi - r[SEG_PHI0]) / (r[SEG_F] * r[SEG_EA])
        lo, hi = r[SEG_T0] - r[SEG_TO], r[SEG_T1] - r[SEG_TO]
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if phase_profile(mid, r[SEG_PHI0], r[SEG_F], r[SEG_EA], r[SEG_EB], r[SEG_TR])[0] < phi:
                lo = mid
            else:
                hi = mid
        return r[SEG_TO] + 0.5 * (lo + hi)

    # -- the window the fleet evaluates ------------------------------------------------------------
    def window(self, t_first: float, t_last: float) -> tuple[np.ndarray, np.ndarray, int, float]:
        """Rows covering ``[t_first, t_last]`` and beyond: (time rows, path rows, id of the first
        path row, end time of the last time row). Rows that ended by ``t_first`` are forgotten."""
        drop = 0
        while drop < len(self.rows) - 1 and self.rows[drop][SEG_T1] <= t_first:
            drop += 1
        del self.rows[:drop]
        self.extend(t_last)
        lo = int(min(r[SEG_LO] for r in self.rows))
        hi = int(max(r[SEG_HI] for r in self.rows))
        if lo > self.piece_base:
            del self.pieces[: lo - self.piece_base]
            self.piece_base = lo
        seg = np.array(self.rows, dtype=float).reshape(-1, NSEG)
        pcs = np.array(self.pieces[: hi - self.piece_base + 1], dtype=float).reshape(-1, NPC)
        return seg, pcs, self.piece_base, self.rows[-1][SEG_T1]

    # -- interruptions ------------------------------------------------------------------------------
    def _cut(self, i: int, at: float) -> list[list[float]]:
        """Rows before ``at``: rows[:i] and row i ending at ``at`` (if it started before)."""
        keep = self.rows[:i]
        if self.rows[i][SEG_T0] < at:
            r = list(self.rows[i])
            r[SEG_T1] = at
            keep.append(r)
        return keep

    def _forever(self, rows: list[list[float]], piece: int) -> None:
        self.rows = rows
        del self.pieces[piece - self.piece_base + 1:]
        self.finished = True
        self.t_end = math.inf
        self.version += 1

    def collapse(self, at: float) -> None:
        """At ``at`` the walker drops where it is: the phone tips to ``fall_pitch_rad`` over ``fall_s``
        and then lies still for good (an abrupt stop, as a fall is)."""
        s = self.s
        self.extend(at)
        st = self.state_at(at)
        keep = self._cut(st.row, at)
        fall_end = at + s.fall_s
        # the sway of the moment becomes the start of the fall: the attitude does not jump
        sy, sp, sr = sway_at(st.phi, st.g, self.traits.row, s)
        yaw, pitch, roll = st.yaw + sy, st.pitch + sp, st.roll + sr
        keep.append(self._row(at, fall_end, st.phi, y0=yaw, p0=pitch, dp=s.fall_pitch_rad - pitch, r0=roll, dr=-roll,
                              ta=s.fall_s, lo=st.piece, hi=st.piece))
        keep.append(self._row(fall_end, math.inf, st.phi, y0=yaw, p0=s.fall_pitch_rad, lo=st.piece, hi=st.piece))
        self._forever(keep, st.piece)

    def stand_still(self, seconds: float, at: float) -> None:
        """From ``at`` the walker slows to a stop within about a step (ending on a whole step
        when it can), stands for ``seconds`` (``inf``: for good) and walks on along its plan.

        Standing already, or slowing for a planned stop: that stop lasts ``seconds`` longer.
        """
        if not seconds > 0:
            raise ValueError(f"stand_still needs seconds > 0, got {seconds!r}")
        s = self.s
        self.extend(at + 30.0)  # the stop and the restart lie a few seconds after `at`
        st = self.state_at(at)
        r = self.rows[st.row]
        if r[SEG_F] == 0.0 and (r[SEG_DY] or r[SEG_DP] or r[SEG_DR]):
            return self._insert_pause(max(at, r[SEG_T1]), seconds)  # finish turning first
        if r[SEG_F] == 0.0 or st.e <= 1e-9:
            return self._insert_pause(at, seconds)
        if _stopping(r):
            return self._insert_pause(r[SEG_T1], seconds)
        v = r[SEG_F] * st.e  # cycles per second now
        phi_end = float(math.ceil(st.phi + 0.25 * v * s.ramp_s))
        t_brake = 2.0 * (phi_end - st.phi) / v
        if t_brake > 3.0 * s.ramp_s:  # barely moving (just starting): a plain ramp, off the whole step
            t_brake, phi_end = s.ramp_s, st.phi + 0.5 * v * s.ramp_s
        phi_join = phi_end + 0.5 * r[SEG_F] * s.ramp_s
        j = st.row
        while True:  # the cruising row where the plan passes phi_join, unless a planned stop comes first
            rj = self.rows[j]
            if rj[SEG_F] == 0.0:
                return self._insert_pause(rj[SEG_T0], seconds)
            if _stopping(rj):
                return self._insert_pause(rj[SEG_T1], seconds)
            end = self.rows[j + 1][SEG_PHI0]
            if end > phi_join:
                if rj[SEG_EB] == 0.0:
                    break
                phi_join = end  # starting or changing cadence: rejoin where the row ends
            j += 1
        f = self.rows[j][SEG_F]
        p_now = st.piece
        p_end = self.piece_for(phi_end, p_now, self.last_piece)
        keep = self._cut(st.row, at)
        t1 = at + t_brake
        keep.append(self._row(at, t1, st.phi, r[SEG_F], 0.5 * st.e, 0.5 * st.e, t_brake, lo=p_now, hi=p_end))
        if math.isinf(seconds):
            keep.append(self._row(t1, math.inf, phi_end, lo=p_end, hi=p_end))
            return self._forever(keep, p_end)
        t2 = t1 + seconds
        t_up = 2.0 * (phi_join - phi_end) / f
        t3 = t2 + t_up
        keep.append(self._row(t1, t2, phi_end, lo=p_end, hi=p_end))
        keep.append(self._row(t2, t3, phi_end, f, 0.5, -0.5, t_up, lo=p_end, hi=self.piece_for(phi_join, p_end, self.last_piece)))
        shift = t3 - self._time_of_phase(self.rows[j], phi_join)
        rest = [list(self.rows[j])] + [list(x) for x in self.rows[j + 1:]]
        for x in rest:
            x[SEG_T0] += shift
            x[SEG_T1] += shift
            x[SEG_TO] += shift
        rest[0][SEG_T0] = t3
        self.rows = keep + rest
        self.t_end += shift
        self.version += 1

    def _insert_pause(self, at: float, seconds: float) -> None:
        """Stand still from ``at`` (a moment the walker is not moving) for ``seconds``; later rows wait."""
        st = self.state_at(at)
        r = self.rows[st.row]
        keep = self._cut(st.row, at)
        pause = self._row(at, at + seconds, st.phi, y0=st.yaw, p0=st.pitch, r0=st.roll, lo=st.piece, hi=st.piece)
        if math.isinf(seconds):
            return self._forever(keep + [pause], st.piece)
        rest = [list(r)] + [list(x) for x in self.rows[st.row + 1:]]
        for x in rest:
            x[SEG_T0] += seconds
            x[SEG_T1] += seconds
            x[SEG_TO] += seconds
        rest[0][SEG_T0] = at + seconds
        self.rows = keep + [pause] + rest
        self.t_end += seconds
        self.version += 1
