"""What happens a few times a second per responder: detected steps become :class:`StepEvent`,
floor changes become :class:`FloorEvent`, in one time-ordered stream.

The per-sample work of the dead reckoning runs in compiled kernels over many responders at
once (:mod:`pdr.fleet`); each responder keeps one :class:`StepAssembler` and one
:class:`FloorEvents` for the rare events.

**A step** (:meth:`StepAssembler.assemble`), given its detection and its heading:

* length ``L = a + b·f`` from the responder's profile (:func:`pdr.step_length.step_lengths`,
  seed 002 §2.8), clipped to ``[min_step_length_m, max_step_length_m]``; on stairs
  (:class:`pdr.floors.StairsDetector` on the per-step height change) whole treads instead
  (seed 000 §7: 0.80 m estimated against 0.28 m real); uncertainty ``σ_L = σ_0 + k·L``;
* height change ``dz = h(t_k) − h(t_{k−1})`` where ``h(t)`` is the height at the last
  pressure sample at or before ``t`` — never a later one, so the answer does not depend on
  whether the next pressure sample came in the same frame;
* the floor the barometer had at ``t_k``.

**Floor events** (:meth:`FloorEvents.release`): a floor change from the barometer (not from a
fix) goes into the stream in time order with the steps: steps at or before the change come
before it, later ones after it. A change is released once the newest sample is
``floor_event_hold_s`` past it (every step before it has been detected by then: the norm
detector releases a bout's first steps at most ≈3 s late); steps after a change wait for it.
So the stream is the same whatever the batching, and a responder in a lift is moved to the
new floor without a step.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from pdr.events import FloorEvent, StepDetection, StepEvent
from pdr.floors import FloorChange, StairsDetector
from pdr.heading import StepHeadings
from pdr.pipeline_settings import PipelineSettings
from pdr.step_length import step_arrays, step_lengths


class StepAssembler:
    """Detected steps of one responder -> :class:`StepEvent` (module docstring)."""

    def __init__(self, settings: PipelineSettings):
        self.settings = settings
        self.count = 0  # steps emitted so far
        self._stairs = StairsDetector(settings.stairs)
        self._detected: list[StepDetection] = []  # detected steps waiting for their heading
        self._last: tuple[float, float] | None = None  # (t, height) of the previous step
        self._intervals: tuple = ()  # s, the recent intervals between steps (the walking cadence, _bridge)

    def detected(self, found: list[StepDetection]) -> None:
        """Steps the detector found; each is assembled once its heading is known."""
        self._detected += found

    def reanchor(self, height_m: float) -> None:
        """The height was re-referenced (a fix): the previous step counts as at ``height_m``."""
        if self._last is not None:
            self._last = (self._last[0], float(height_m))

    def assemble(self, hd: StepHeadings, pressure: np.ndarray, floor_at: Callable[[float], int]) -> list[StepEvent]:
        """The first ``len(hd)`` detected steps with their headings ``hd``; ``pressure`` holds
        rows (t, height) of the recent pressure samples, ``floor_at`` the barometer's floor."""
        return assemble_round([(self, hd, pressure, floor_at)])[0]

    # the three parts of assembling, for assemble_round: take the steps, where the last one
    # was, emit the events (the per-responder part: stairs windows and step indices)
    def take(self, n: int) -> list[StepDetection]:
        """The first ``n`` detected steps, no longer waiting."""
        det, self._detected = self._detected[:n], self._detected[n:]
        return det

    @property
    def last_height(self) -> float:
        """m, the height at the previous step (NaN before the first or without a barometer)."""
        return self._last[1] if self._last else math.nan

    def emit(self, hd: StepHeadings, L: np.ndarray, h: np.ndarray, dz: np.ndarray, dz_sigma: np.ndarray,
             floor_at: Callable[[float], int]) -> list[StepEvent]:
        """The events of steps with headings ``hd``, model lengths ``L``, heights ``h`` and height
        changes ``dz`` (σ ``dz_sigma``); on stairs the stairs detector's lengths instead."""
        s = self.settings
        stairs = self._stairs.update(dz)
        L = np.where(stairs.on_stairs, stairs.length, L)
        sigma_L = s.length_sigma_m + s.length_sigma_frac * L
        L, sigma_L = self._bridge(hd, np.asarray(L, float), np.asarray(sigma_L, float))
        events = []
        for k in range(len(hd)):
            self.count += 1
            events.append(StepEvent(
                t=float(hd.t[k]), index=self.count, length=float(L[k]), length_sigma=float(sigma_L[k]),
                heading=float(hd.heading[k]), heading_sigma=float(hd.heading_sigma[k]),
                heading_change=float(hd.heading_change[k]) if self.count > 1 else 0.0,
                heading_change_sigma=float(hd.heading_change_sigma[k]),
                dz=float(dz[k]), dz_sigma=float(dz_sigma[k]), floor=int(floor_at(float(hd.t[k]))),
                on_stairs=bool(stairs.on_stairs[k]), mag_heading=float(hd.mag_heading[k]),
                mag_heading_sigma=float(hd.mag_heading_sigma[k]),
            ))
        self._last = (float(hd.t[-1]), float(h[-1]))
        return events

    _intervals: tuple = ()  # (a snapshot from before gaps were bridged: none yet)

    def _bridge(self, hd: StepHeadings, L: np.ndarray, sigma_L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A gap in the samples hides the steps walked in it: nothing is logged, and the
        detector's filter starts again after it. So the first step after such a gap (its heading
        change unknown, :func:`pdr.windows.spans_gap`) that comes ``n`` step periods after the
        previous step, walking before it (the median of the last 8 intervals under 1 s, at least
        4 of them: ``T``), stands for the ``n`` steps walked::

            n = round(Δt / T)   when 1.6 T < Δt ≤ bridge_max_s:   L ← n L,  σ_L ← √n σ_L

        A pause with samples (a walker who stops and goes on) keeps its heading change and is not
        bridged. Robustness suite ``gaps`` (one 0.2-2 s gap every 30 s): the walked path was
        1.1-6.0 % short on 10 walks (docs/robustness.md, round 13). A change of grip (a jump of
        :mod:`pdr.grip`) also leaves the heading change unknown: under ``hold_z`` the rule fired
        on two walks, both better (T24r03 3.16 → 2.93 m, T53r02 5.91 → 5.45 m live p75). A
        walker who stops to change grip would be counted steps too many; not seen in the suite."""
        s = self.settings
        prev = self._last[0] if self._last else math.nan
        iv = list(self._intervals)
        L, sigma_L = L.copy(), sigma_L.copy()  # the caller's arrays stay as they were
        for k in range(len(hd)):
            t = float(hd.t[k])
            dt = t - prev
            prev = t
            if not math.isfinite(dt):
                continue
            T = float(np.median(iv)) if len(iv) >= 4 else math.nan
            if (not math.isfinite(float(hd.heading_change_sigma[k])) and math.isfinite(T)
                    and 1.6 * T < dt <= s.bridge_max_s):
                n = round(dt / T)
                L[k] *= n
                sigma_L[k] *= math.sqrt(n)
            elif dt < 1.0:
                iv = (iv + [dt])[-8:]
        self._intervals = tuple(iv)
        return L, sigma_L


# a member's job for assemble_round: its assembler, headings, pressure rows (t, height) and floor_at
AssemblyJob = tuple[StepAssembler, StepHeadings, np.ndarray, Callable[[float], int]]


def assemble_round(jobs: list[AssemblyJob]) -> list[list[StepEvent]]:
    """:meth:`StepAssembler.assemble` of many responders at once (a columnar round's): each
    job is ``(assembler, headings, pressure, floor_at)``. The lengths, heights and height
    changes of every job's steps are computed in one pass over their concatenated columns:
    each is elementwise (the step-length models' regressors and :func:`pdr.fixed_order.row_dot`
    included), so every step gets the same bits as alone. Only the stairs windows, which
    carry each responder's previous steps, go one responder at a time."""
    out: list[list[StepEvent]] = [[] for _ in jobs]
    live = [(i, job) for i, job in enumerate(jobs) if len(job[1])]
    if not live:
        return out
    ns = [len(hd) for _, (_, hd, _, _) in live]
    dets = []
    for (_, (a, _, _, _)), n in zip(live, ns):
        dets += a.take(n)
    L = np.empty(len(dets))
    for s, rows in _rows_by_settings(live, ns):  # one pass per settings (a fleet's members share theirs)
        L[rows] = np.clip(step_lengths(step_arrays([dets[r] for r in rows.tolist()]), s.profile),
                          s.min_step_length_m, s.max_step_length_m)
    h = np.concatenate([_height_before(pr, hd.t) for _, (_, hd, pr, _) in live])
    firsts = np.array([a.last_height for _, (a, _, _, _) in live])
    starts = np.cumsum([0] + ns[:-1])
    h_prev = np.concatenate(([np.nan], h[:-1]))
    h_prev[starts] = firsts  # each responder's first step follows its own previous one
    known = np.isfinite(h) & np.isfinite(h_prev)
    dz = np.where(known, h - h_prev, 0.0)
    dsig = np.array([a.settings.dz_sigma_m for _, (a, _, _, _) in live]).repeat(ns)
    dz_sigma = np.where(known, dsig, math.inf)
    for (i, (a, hd, _, floor_at)), o, n in zip(live, starts.tolist(), ns):
        part = slice(o, o + n)
        out[i] = a.emit(hd, L[part], h[part], dz[part], dz_sigma[part], floor_at)
    return out


def _rows_by_settings(live, ns) -> list[tuple[PipelineSettings, np.ndarray]]:
    """(settings, rows of their steps among the concatenated steps) of the jobs, in order."""
    groups: dict[int, tuple[PipelineSettings, list[np.ndarray]]] = {}
    o = 0
    for (_, (a, _, _, _)), n in zip(live, ns):
        groups.setdefault(id(a.settings), (a.settings, []))[1].append(np.arange(o, o + n))
        o += n
    return [(s, np.concatenate(rows)) for s, rows in groups.values()]


def _height_before(pressure: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Height at the last pressure sample at or before each ``t`` (NaN before any)."""
    if pressure.shape[0] == 0:
        return np.full(t.shape, np.nan)
    i = np.searchsorted(pressure[:, 0], t, side="right") - 1
    return np.where(i >= 0, pressure[np.maximum(i, 0), 1], np.nan)


class FloorEvents:
    """One responder's floor changes waiting to be released, and the steps held behind them."""

    def __init__(self):
        self._queue: list[FloorChange] = []  # changes not yet released as FloorEvent
        self._held: list[StepEvent] = []  # steps after an unreleased change

    @property
    def waiting(self) -> bool:
        """A change or a step is held (a later round may release it without new steps)."""
        return bool(self._queue or self._held)

    def changed(self, change: FloorChange) -> None:
        self._queue.append(change)

    def superseded(self) -> None:
        """A fix re-referenced the floor: the changes the barometer made before it are void."""
        self._queue = []

    def release(self, steps: list[StepEvent], horizon: float) -> list[StepEvent | FloorEvent]:
        """Steps and floor events in time order: changes up to ``horizon``, and the steps
        before the first change still held (module docstring)."""
        self._held += steps
        out: list[StepEvent | FloorEvent] = []
        while self._queue and self._queue[0].t <= horizon:
            c = self._queue.pop(0)
            out += self._take_until(c.t)
            out.append(FloorEvent(t=c.t, floor=c.floor_to, floor_from=c.floor_from, reason=c.reason))
        return out + self._take_until(self._queue[0].t if self._queue else math.inf)

    def _take_until(self, bound: float) -> list[StepEvent]:
        n = sum(1 for e in self._held if e.t <= bound)
        out, self._held = self._held[:n], self._held[n:]
        return out


__all__ = ["StepAssembler", "FloorEvents", "assemble_round"]
