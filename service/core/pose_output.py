"""What the core answers, in order: Statuses, Audits and poses (local ENU and WGS-84, the poses
of a round converted together).

:class:`Outbox` is a collaborator of :class:`service.core.incident_core.IncidentCore`: the
core's parts put their answers in it and the core takes the round's answers out.
"""
from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from pdr.events import bearing_deg
from service.core.core_types import CoreCounters, Outbound
from service.core.responder import Responder
from service.core.tracker import PoseEstimate
from service.protocol import wire
from service.protocol.incident import IncidentConfig

log = logging.getLogger("firetrack.service")


class _Pending(NamedTuple):
    """A pose waiting for the round's end, with what its wire form takes from that moment."""

    place: int  # its index among the round's answers
    responder: Responder
    pose: PoseEstimate
    seq: int  # the newest frame's seq when it was made
    now: float  # the core's time then (published_at)
    utc_offset: float | None


class Outbox:
    """A round's answers. A pose keeps its place in the order; its wire form is made with the
    round's other poses (one geodetic conversion) when the round's answers are taken."""

    def __init__(self, incident: IncidentConfig, counters: CoreCounters):
        self.incident = incident
        self.counters = counters
        self.audits = 0  # Audits answered so far
        self._out: list[Outbound | None] = []
        self._poses: list[_Pending] = []

    def put(self, o: Outbound) -> None:
        self._out.append(o)

    def audit(self, a: wire.Audit) -> None:
        """An operator action's (or a flagged fix's) outcome, on ``.../{actor}/audit``."""
        self.audits += 1
        self._out.append(Outbound(wire.key(self.incident.id, a.actor, "audit"), a))

    def pose(self, r: Responder, p: PoseEstimate, now: float) -> None:
        """A pose of ``r`` to answer (``now``: the core's time, the Pose's ``published_at``)."""
        self._poses.append(_Pending(len(self._out), r, p, max(r.seq, 0), now, r.utc_offset))
        self._out.append(None)
        r.poses += 1

    def take(self, stamp: Callable[[], float] | None = None) -> list[Outbound]:
        """The answers so far, in order, the poses in their wire form; the outbox is empty after.
        ``stamp``: the clock whose reading, taken once here as the poses are made, is every
        pose's ``published_at`` (the live shell's wall clock, just before it publishes them);
        None: each pose carries the core's time of its round (reprocess, benches, tests)."""
        self._emit_poses(stamp)
        out, self._out = self._out, []
        return out

    def _emit_poses(self, stamp: Callable[[], float] | None) -> None:
        q, self._poses = self._poses, []
        if not q:
            return
        at = None if stamp is None else float(stamp())
        try:
            lat, lon = self.geodetic(np.array([e.pose.x for e in q], float), np.array([e.pose.y for e in q], float))
            lat, lon = lat.tolist(), lon.tolist()
        except Exception:
            self.counters.errors += 1
            log.exception("geodetic position of %d poses", len(q))
            lat = lon = [math.nan] * len(q)
        for e, la, lo in zip(q, lat, lon):
            r = e.responder
            try:
                self._out[e.place] = Outbound(wire.key(self.incident.id, r.id, "pose"),
                                              pose_message(r, e.pose, la, lo, e.seq, e.now if at is None else at,
                                                           e.utc_offset))
            except Exception:  # a pose that is not a valid message is dropped, counted and logged
                self.counters.errors += 1
                log.exception("pose of %s", r.id)
        if any(o is None for o in self._out):
            self._out = [o for o in self._out if o is not None]

    def geodetic(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ENU -> (lat, lon) for arrays: every pose the same bits whether converted alone or among many."""
        lat, lon, _ = self.incident.to_geodetic(x, y, np.zeros_like(x))
        return np.atleast_1d(lat), np.atleast_1d(lon)


def pose_message(r: Responder, p: PoseEstimate, lat: float, lon: float, seq: int, now: float, utc_offset) -> wire.Pose:
    """The wire form of a pose: geodetic position, compass bearing, symmetric covariance, the
    time on the current stream's device clock; ``published_at`` is ``now``: the one stamp a
    pose gets (:meth:`PoseOutput.take`)."""
    cov = np.asarray(p.cov, float)
    cov = 0.5 * (cov + cov.T)
    t = p.t - r.t_offset  # on the current stream's device clock, like every time on the wire
    return wire.Pose(
        responder=r.id, t=t, x=p.x, y=p.y, floor=int(p.floor), lat=lat, lon=lon,
        heading_deg=bearing_deg(p.heading) if math.isfinite(p.heading) else 0.0, cov=cov, steps=p.steps,
        source=p.source, seq=seq, published_at=now,
        utc=None if utc_offset is None else t + utc_offset,
    )


class MemberSlot:
    """A fleet member named by its slot in the whole core's pickle, until its responder's pickle
    gives it (:mod:`service.core.core_snapshot`). It stays in this module because snapshots
    name it here."""

    __slots__ = ("slot",)

    def __init__(self, slot: int):
        self.slot = int(slot)
