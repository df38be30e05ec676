"""Who the core knows: its responders, the newcomers (admitted ids none of whose messages has
decoded yet), the liveliness heard before a responder's first frame, and each responder's kept
pickle for the next snapshot (issue 20: a snapshot pickles only the responders that changed).

A responder is read with :meth:`Roster.get` and changed only through :meth:`Roster.changing`,
which also drops its kept pickle: there is no separate "it changed" call to forget, so a snapshot
cannot keep a stale responder. (Only the Status bookkeeping, :data:`VOLATILE`, changes on
responders read with ``get``: it is kept beside the pickles, not in them.)
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator

from service.core import snapshot as snapshots
from service.core.responder import Newcomer, Responder

# fields of a Responder that every tick may change for a silent responder (its Status's
# bookkeeping): kept beside the responders' cached pickles, not in them
VOLATILE = ("last_status", "last_alarms", "alarm_since")


class Roster:
    """The responders of one incident by id, the newcomers and early liveliness, all bounded."""

    MAX_PRESENCE = 4096  # liveliness states kept for ids with no responder (beyond, the oldest go)
    MAX_NEWCOMERS = 4096  # newcomers kept (the intake admits fewer; a core fed past an intake is bounded too)

    def __init__(self, forget_newcomer: Callable[[str, Newcomer], None]):
        """``forget_newcomer(rid, newcomer)``: told when a newcomer leaves without becoming a
        responder (its counts stay in the incident's accounting)."""
        self.responders: dict[str, Responder] = {}
        self.newcomers: dict[str, Newcomer] = {}
        self.presence: dict[str, bool] = {}  # liveliness seen before a responder's first frame
        self.blobs: dict[str, bytes] = {}  # responders' pickles of the last snapshot, while they do not change
        self._on_forget = forget_newcomer

    # ------------------------------------------------------------------ responders
    def get(self, rid: str) -> Responder | None:
        """The responder ``rid`` to read (its Status, its track), or None."""
        return self.responders.get(rid)

    def changing(self, rid: str) -> Responder | None:
        """The responder ``rid`` about to change (a message for it, frames released): its kept
        pickle goes, so the next snapshot pickles it afresh. None for an unknown id."""
        r = self.responders.get(rid)
        if r is not None:
            self.blobs.pop(rid, None)
        return r

    def add(self, r: Responder) -> None:
        self.responders[r.id] = r
        self.blobs.pop(r.id, None)

    def remove(self, rid: str) -> Responder:
        self.blobs.pop(rid, None)
        return self.responders.pop(rid)

    def __iter__(self) -> Iterator[Responder]:
        return iter(list(self.responders.values()))

    def __len__(self) -> int:
        return len(self.responders)

    # ------------------------------------------------------------------ newcomers and early liveliness
    def newcomer(self, rid: str, now: float) -> Newcomer:
        """The newcomer ``rid``, made now if it is new (the oldest goes beyond the bound)."""
        n = self.newcomers.get(rid)
        if n is None:
            if len(self.newcomers) >= self.MAX_NEWCOMERS:  # fed past an intake (reprocess): the oldest goes
                self.forget_newcomer(next(iter(self.newcomers)))
            n = self.newcomers[rid] = Newcomer(first_heard=now, last_input=now)
        return n

    def forget_newcomer(self, rid: str) -> None:
        self._on_forget(rid, self.newcomers.pop(rid))

    def expire_newcomers(self, now: float, silent_s: float) -> None:
        for rid in [rid for rid, n in self.newcomers.items() if now - n.last_input > silent_s]:
            self.forget_newcomer(rid)

    def note_presence(self, rid: str, alive: bool) -> None:
        """Liveliness of ``rid``: on its responder, or kept (bounded) for the responder to come."""
        r = self.changing(rid)
        if r is not None:
            r.present = alive
            return
        self.presence[rid] = alive
        while len(self.presence) > self.MAX_PRESENCE:
            del self.presence[next(iter(self.presence))]

    # ------------------------------------------------------------------ snapshots
    def blob_of(self, r: Responder, refs: snapshots.SharedRefs) -> bytes:
        """``r``'s own pickle, as a snapshot holds it (its Status bookkeeping aside)."""
        return snapshots.dump_responder({k: v for k, v in vars(r).items() if k not in VOLATILE}, refs)

    def all_blobs(self, refs: snapshots.SharedRefs) -> dict[str, bytes]:
        """Every responder's pickle: the kept ones, the others made (and kept) now."""
        for rid, r in self.responders.items():
            if rid not in self.blobs:
                self.blobs[rid] = self.blob_of(r, refs)
        return {rid: self.blobs[rid] for rid in self.responders}

    def prepare(self, limit: int, busy, refs: Callable[[], snapshots.SharedRefs]) -> int:
        """Pickle (and keep) up to ``limit`` of the responders without a kept pickle, skipping
        ``busy`` ids (frames waiting); returns how many are left."""
        shared, left = None, 0
        for rid, r in self.responders.items():
            if rid in self.blobs:
                continue
            if limit <= 0 or r.backlog or rid in busy:
                left += 1
                continue
            shared = shared or refs()
            self.blobs[rid] = self.blob_of(r, shared)
            limit -= 1
        return left

    def volatile(self) -> dict[str, tuple]:
        return {rid: tuple(getattr(r, k) for k in VOLATILE) for rid, r in self.responders.items()}


def restored_responder(fields: dict, volatile: tuple) -> Responder:
    """A responder from its snapshot fields; a field that a snapshot of an older version lacks
    (e.g. ``beacons_heard``) gets its default, so every declared field is there to read."""
    r = object.__new__(Responder)
    for f in dataclasses.fields(Responder):
        if f.name not in fields:
            if f.default is not dataclasses.MISSING:
                setattr(r, f.name, f.default)
            elif f.default_factory is not dataclasses.MISSING:
                setattr(r, f.name, f.default_factory())
    vars(r).update(fields)
    for k, v in zip(VOLATILE, volatile):
        setattr(r, k, v)
    return r
