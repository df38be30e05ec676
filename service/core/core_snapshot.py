"""The whole incident core as bytes, and a core that goes on from them.

The framing, the safe unpickler and the responders' own pickles are :mod:`service.core.snapshot`'s;
this module says what of the core a snapshot holds: each responder's pickle (kept by the
:class:`service.core.roster.Roster` while it does not change), their Status bookkeeping beside
them, the incident-wide counts, the intake's budgets, the access policy, newcomers, held fixes
and the fleet of handheld pipelines. Snapshots of older versions restore: a key they lack takes
its empty value, a responder field they lack its default (:func:`service.core.roster.restored_responder`).
"""
from __future__ import annotations

import dataclasses

from pdr.fleet import FleetMember
from service.core import snapshot as snapshots
from service.core.pose_output import MemberSlot
from service.core.roster import restored_responder


def shared_refs(core) -> snapshots.SharedRefs:
    """What the responders' pickles name instead of holding (:class:`service.core.snapshot.SharedRefs`)."""
    fleet = core.fleet
    return snapshots.SharedRefs(fleet, [core.settings.tracker] + ([fleet.settings, fleet.floors] if fleet else []))


def dump(core) -> bytes:
    """The state of ``core`` (an :class:`service.core.incident_core.IncidentCore`, between rounds) as bytes."""
    if core.frames.dirty or any(r.backlog for r in core.roster):
        core.frames.run_dirty()  # between rounds nothing waits; make sure
    roster = core.roster
    state = {"incident": core.id, "responders": roster.all_blobs(shared_refs(core)), "volatile": roster.volatile(),
             "tracker_settings": core.settings.tracker, "unattributed": core.rejects.unattributed,
             "counters": core.counters, "presence": roster.presence, "intake": core.intake, "now": core.clock.now,
             "access": core.desk.access, "newcomers": roster.newcomers, "held_fixes": core.fixes.held,
             "fleet": core.fleet, "expiry_checked": core.expiry_checked}
    # the fleet's members are its responders': the fleet names them by slot
    return snapshots.dumps(state, {FleetMember: _member_slot_of})


def load(core, blob: bytes):
    """``core`` (new, of the snapshot's incident, with today's settings) put in the state of ``blob``."""
    state = snapshots.loads(blob)
    if state.get("incident") != core.id:
        raise ValueError(f"the snapshot is of incident {state.get('incident')!r}, not {core.id!r}")
    fleet, tracker_settings = state["fleet"], state["tracker_settings"]
    same = _same(tracker_settings, core.settings.tracker)
    if same:  # the restored trackers share the core's settings again
        core.settings = dataclasses.replace(core.settings, tracker=tracker_settings)
    refs = snapshots.SharedRefs(fleet, [tracker_settings] + ([fleet.settings, fleet.floors] if fleet else []))
    responders = {rid: restored_responder(snapshots.load_responder(b, refs), state["volatile"][rid])
                  for rid, b in state["responders"].items()}
    if fleet is not None:  # the members named by slot in the fleet are those the responders hold
        held = {r.tracker.model.slot: r.tracker.model for r in responders.values()
                if isinstance(r.tracker.model, FleetMember)}
        try:
            fleet.members = [held[m.slot] for m in fleet.members]
        except KeyError as e:
            raise snapshots.SnapshotError(f"the snapshot's fleet has a member (slot {e}) no responder holds") from None
        core.fleet = fleet  # the restored handheld trackers' slots live in it: new ones join it
    core.counters = state["counters"]
    intake = state["intake"]
    intake.settings = core.settings.intake  # today's budgets over yesterday's counts
    core.intake = intake
    core.assemble(unattributed=state["unattributed"], held_fixes=state.get("held_fixes") or {})  # before issue 32: none
    roster = core.roster
    roster.responders = responders
    if same:  # still each responder's pickle (which names the settings it shares by their place in them)
        roster.blobs = dict(state["responders"])
    roster.presence = state["presence"]
    roster.newcomers = state["newcomers"]
    core.clock.now = state["now"]
    core.expiry_checked = state["expiry_checked"]
    core.desk.restore_policy(state["access"])
    return core


def _same(a, b) -> bool:
    """Equal settings (dataclasses of numbers and names; by their reprs, since ``==`` says a NaN
    field differs from itself)."""
    return type(a) is type(b) and repr(a) == repr(b)


def _member_slot_of(m: FleetMember):
    return MemberSlot, (m.slot,)
