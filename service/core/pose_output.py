"""Poses out (local ENU and WGS-84, a round at a time) and snapshots of the whole core.

A mixin of :class:`service.core.incident_core.IncidentCore` (its state and settings).
"""
from __future__ import annotations

import dataclasses
import logging
import math
from typing import Self

import numpy as np

from pdr.events import bearing_deg
from pdr.fleet import FleetMember
from service.core import snapshot as snapshots
from service.core.core_types import (
    CoreSettings,
    Outbound,
)
from service.core.responder import Responder
from service.core.tracker import (
    PoseEstimate,
)
from service.protocol import wire
from service.protocol.incident import IncidentConfig

log = logging.getLogger("firetrack.service")


class PoseOutput:
    """Poses out (local ENU and WGS-84, a round at a time) and snapshots of the whole core."""

    def _answer_pose(self, r: Responder, p: PoseEstimate) -> None:
        """A pose to answer: its place in the output is kept, its wire form is made for all the
        round's poses at once (one geodetic conversion, :meth:`_emit_poses`)."""
        self._pose_queue.append((len(self._out), r, p, max(r.seq, 0), self._now, r.utc_offset))
        self._out.append(None)
        r.poses += 1

    def _emit_poses(self) -> None:
        q, self._pose_queue = self._pose_queue, []
        if not q:
            return
        try:
            lat, lon = self._geodetic(np.array([e[2].x for e in q], float), np.array([e[2].y for e in q], float))
            lat, lon = lat.tolist(), lon.tolist()
        except Exception:
            self.counters.errors += 1
            log.exception("geodetic position of %d poses", len(q))
            lat = lon = [math.nan] * len(q)
        for (i, r, p, seq, now, utc_offset), la, lo in zip(q, lat, lon):
            try:
                self._out[i] = Outbound(wire.key(self.id, r.id, "pose"), self._pose(r, p, la, lo, seq, now, utc_offset))
            except Exception:  # a pose that is not a valid message is dropped, counted and logged
                self.counters.errors += 1
                log.exception("pose of %s", r.id)
        if any(o is None for o in self._out):
            self._out = [o for o in self._out if o is not None]

    def _geodetic(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ENU -> (lat, lon) for arrays: every pose the same bits whether converted alone or among many."""
        lat, lon, _ = self.incident.to_geodetic(x, y, np.zeros_like(x))
        return np.atleast_1d(lat), np.atleast_1d(lon)

    def pose_message(self, r: Responder, p: PoseEstimate) -> wire.Pose:
        """The wire form of a pose: geodetic position, compass bearing, symmetric covariance;
        ``published_at`` is the core's time, which the shell restamps when it publishes."""
        lat, lon = self._geodetic(np.array([p.x], float), np.array([p.y], float))
        return self._pose(r, p, float(lat[0]), float(lon[0]), max(r.seq, 0), self._now, r.utc_offset)

    @staticmethod
    def _pose(r: Responder, p: PoseEstimate, lat: float, lon: float, seq: int, now: float, utc_offset) -> wire.Pose:
        cov = np.asarray(p.cov, float)
        cov = 0.5 * (cov + cov.T)
        t = p.t - r.t_offset  # on the current stream's device clock, like every time on the wire
        return wire.Pose(
            responder=r.id, t=t, x=p.x, y=p.y, floor=int(p.floor), lat=lat, lon=lon,
            heading_deg=bearing_deg(p.heading) if math.isfinite(p.heading) else 0.0, cov=cov, steps=p.steps,
            source=p.source, seq=seq, published_at=now,
            utc=None if utc_offset is None else t + utc_offset,
        )

    # fields of a Responder that every tick may change for a silent responder (its Status's
    # bookkeeping): kept beside the responders' cached pickles, not in them
    VOLATILE = ("last_status", "last_alarms", "alarm_since")

    def snapshot(self) -> bytes:
        """The core's state as bytes (between rounds): every responder (gate, motion model,
        estimator, counters), the intake's budgets and the counters. Not the incident config or
        the settings: :meth:`restore` takes those from the caller. A responder that has not
        changed since the last snapshot is not pickled again (:mod:`service.core.snapshot`)."""
        if self._dirty or any(r.backlog for r in self.responders.values()):
            self._run_dirty()  # between rounds nothing waits; make sure
        refs = self._shared_refs()
        blobs = self._blobs
        for rid, r in self.responders.items():
            if rid not in blobs:
                blobs[rid] = self.responder_blob(r, refs)
        volatile = {rid: tuple(getattr(r, k) for k in self.VOLATILE) for rid, r in self.responders.items()}
        state = {"incident": self.id, "responders": {rid: blobs[rid] for rid in self.responders},
                 "volatile": volatile, "tracker_settings": self.settings.tracker, "unattributed": self.unattributed,
                 "counters": self.counters, "presence": self._presence, "intake": self.intake, "now": self._now,
                 "access": self.access, "newcomers": self._newcomers, "held_fixes": self._held_fixes, "fleet": self.fleet,
                 "expiry_checked": self._expiry_checked}
        # the fleet's members are its responders': the fleet names them by slot
        return snapshots.dumps(state, {FleetMember: _member_slot_of})

    def prepare_snapshot(self, limit: int) -> int:
        """Pickle (and keep) up to ``limit`` of the responders the next snapshot would pickle
        afresh; returns how many are left. The shell spreads a crowd's pickling over rounds this
        way (a burst of newly admitted ids is not one long stall); what it keeps stays valid
        until the responder changes, like any kept pickle."""
        refs, left = None, 0
        for rid, r in self.responders.items():
            if rid in self._blobs:
                continue
            if limit <= 0 or r.backlog or rid in self._dirty:
                left += 1
                continue
            refs = refs or self._shared_refs()
            self._blobs[rid] = self.responder_blob(r, refs)
            limit -= 1
        return left

    def responder_blob(self, r: Responder, refs=None) -> bytes:
        """``r``'s own pickle, as a snapshot holds it (its Status bookkeeping aside)."""
        refs = refs or self._shared_refs()
        return snapshots.dump_responder({k: v for k, v in vars(r).items() if k not in self.VOLATILE}, refs)

    def _shared_refs(self) -> snapshots.SharedRefs:
        fleet = self.fleet
        return snapshots.SharedRefs(fleet, [self.settings.tracker] + ([fleet.settings, fleet.floors] if fleet else []))

    def _touch(self, r: Responder) -> None:
        """``r`` changes: its cached pickle goes (the next snapshot pickles it again)."""
        self._blobs.pop(r.id, None)

    @classmethod
    def restore(cls, blob: bytes, incident: IncidentConfig, settings: CoreSettings | None = None) -> Self:
        """A core that goes on from :meth:`snapshot`'s bytes (taken by a core of the same incident)."""
        core = cls(incident, settings)
        state = snapshots.loads(blob)
        if state.get("incident") != core.id:
            raise ValueError(f"the snapshot is of incident {state.get('incident')!r}, not {core.id!r}")
        fleet, tracker_settings = state["fleet"], state["tracker_settings"]
        same = _same(tracker_settings, core.settings.tracker)
        if same:  # the restored trackers share the core's settings again
            core.settings = dataclasses.replace(core.settings, tracker=tracker_settings)
        refs = snapshots.SharedRefs(fleet, [tracker_settings] + ([fleet.settings, fleet.floors] if fleet else []))
        responders = {}
        for rid, b in state["responders"].items():
            r = object.__new__(Responder)
            vars(r).update(snapshots.load_responder(b, refs))
            for k, v in zip(cls.VOLATILE, state["volatile"][rid]):
                setattr(r, k, v)
            responders[rid] = r
        if fleet is not None:  # the members named by slot in the fleet are those the responders hold
            held = {r.tracker.model.slot: r.tracker.model for r in responders.values()
                    if isinstance(r.tracker.model, FleetMember)}
            try:
                fleet.members = [held[m.slot] for m in fleet.members]
            except KeyError as e:
                raise snapshots.SnapshotError(f"the snapshot's fleet has a member (slot {e}) no responder holds") from None
            core.fleet = fleet  # the restored handheld trackers' slots live in it: new ones join it
        core.responders = responders
        if same:  # still each responder's pickle (which names the settings it shares by their place in them)
            core._blobs = dict(state["responders"])
        core.unattributed = state["unattributed"]
        core.counters = state["counters"]
        core._presence = state["presence"]
        intake = state["intake"]
        intake.settings = core.settings.intake  # today's budgets over yesterday's counts
        core.intake = intake
        core._now = state["now"]
        core._expiry_checked = state["expiry_checked"]
        acc = state["access"]
        core.access, core._revoked = acc, frozenset(acc.revoked) if acc.enforce else frozenset()
        intake.set_roster(frozenset(acc.wearables))  # today's roster and the policy's wearables
        core._newcomers = state["newcomers"]
        core._held_fixes = state.get("held_fixes", {})  # snapshots before issue 32 have none
        return core


def _same(a, b) -> bool:
    """Equal settings (dataclasses of numbers and names; by their reprs, since ``==`` says a NaN
    field differs from itself)."""
    return type(a) is type(b) and repr(a) == repr(b)


class MemberSlot:
    """A fleet member named by its slot in the whole core's pickle, until its responder's pickle gives it."""

    __slots__ = ("slot",)

    def __init__(self, slot: int):
        self.slot = int(slot)


def _member_slot_of(m: FleetMember):
    return MemberSlot, (m.slot,)
