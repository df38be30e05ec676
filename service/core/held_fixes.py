"""Fixes for ids that have no responder: held a little, never a reason to make one (issue 32).

A fix names a responder by its key; anyone the router lets put fixes (an anchor, an operator's
tool) can name any id. A responder is made only by its wearable's frames, so a fix for an id
with no responder is held (at most :attr:`HeldFixes.MAX_HELD_FIXES` over all ids, for
:attr:`HeldFixes.HELD_FIX_S`): a wearable whose door fix went out just before its first frame
is still placed by it, and fixes for ids that never send a frame are dropped and counted
(``fix_unknown_responder``), with no responder, Status or console row made for them.

A mixin of :class:`service.core.incident_core.IncidentCore` (its state, settings and log).
"""
from __future__ import annotations

from service.core.responder import Responder
from service.protocol import wire


class HeldFixes:
    """Fixes waiting for their responder's first frame."""

    MAX_HELD_FIXES = 256  # fixes kept for ids with no responder (over all ids; beyond, the oldest go)
    HELD_FIX_S = 10.0  # s such a fix waits for its responder's first frame
    _held_fixes: dict = {}  # rid -> [(received, Fix)]: fixes that came before their responder's first frame

    def _hold_fix(self, rid: str, fix: wire.Fix, now: float) -> None:
        """A fix for an id with no responder: held (bounded) for :data:`HELD_FIX_S`, so a
        wearable's door fix sent just before its first frame still places it; anything else
        (a fix for an id that never sends a frame) is dropped, counted ``fix_unknown_responder``."""
        if not self._held_fixes:
            self._held_fixes = {}
        held = self._held_fixes
        held.setdefault(rid, []).append((now, fix))
        while sum(len(v) for v in held.values()) > self.MAX_HELD_FIXES:
            old = next(iter(held))
            held[old].pop(0)
            if not held[old]:
                del held[old]
            self._unattributed("fix_unknown_responder", old, "held fixes over their bound", now)

    def _take_held_fixes(self, r: Responder, now: float) -> None:
        """The fixes held for a responder just made, in the order they came (as if it had been there)."""
        for received, fix in self._held_fixes.pop(r.id, []) if self._held_fixes else []:
            if now - received <= self.HELD_FIX_S:
                self._take_fix(r, fix)
            else:
                self._unattributed("fix_unknown_responder", r.id, "a fix that came too long before its first frame", now)

    def _expire_held_fixes(self, now: float) -> None:
        for rid in [rid for rid, v in self._held_fixes.items() if now - v[-1][0] > self.HELD_FIX_S]:
            for _ in self._held_fixes.pop(rid):
                self._unattributed("fix_unknown_responder", rid, f"no frame of {rid!r} came within "
                                                              f"{self.HELD_FIX_S:g} s of its fix", now)

    def _unattributed(self, reason: str, rid: str, detail: str, now: float) -> None:
        self.unattributed[reason] = self.unattributed.get(reason, 0) + 1
        self.reject_log.note("<unknown responders>", reason, f"{rid}: {detail}", now)
