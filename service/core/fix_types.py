"""Fix types: how a wire ``Fix`` of each source becomes a fix in the incident's local frame.

A fix type is registered under its wire ``source`` name (:func:`register_fix_type`); the
incident core looks it up for every fix message. ``to_domain`` raises :class:`FixRejected`
with a counted reason when the fix cannot be used (an unknown checkpoint or anchor).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from service.fusion.fixes import CheckpointFix, GnssFix, UwbRange
from service.protocol.incident import UnknownCheckpointError


class FixRejected(ValueError):
    """A fix that cannot be used; ``reason`` is its Status counter name."""

    def __init__(self, reason: str, detail: str):
        super().__init__(detail)
        self.reason = reason


@dataclass(frozen=True)
class FixType:
    source: str
    to_domain: Callable  # (wire fix, incident config) -> domain fix


_TYPES: dict[str, FixType] = {}


def register_fix_type(ft: FixType) -> FixType:
    _TYPES[ft.source] = ft
    return ft


def fix_type_of(source: str) -> FixType:
    try:
        return _TYPES[source]
    except KeyError:
        raise FixRejected("unknown_source", f"no fix type {source!r} is registered (known: {', '.join(_TYPES)})") from None


def _checkpoint(fix, cfg) -> CheckpointFix:
    if fix.name is not None:
        try:
            cp = cfg.checkpoint(fix.name)
        except UnknownCheckpointError as e:
            raise FixRejected("unknown_reference", str(e)) from None
        floor = fix.floor if fix.floor is not None else cp.floor
        return CheckpointFix(fix.t, cp.x, cp.y, floor, fix.sigma or cp.sigma_m, cp.name)
    return CheckpointFix(fix.t, fix.x, fix.y, fix.floor, fix.sigma or 0.5, None)


def _gnss(fix, cfg) -> GnssFix:
    x, y, _ = cfg.to_enu(fix.lat, fix.lon)
    return GnssFix(t=fix.t, x=float(x), y=float(y), accuracy=fix.accuracy)


def _uwb(fix, cfg) -> UwbRange:
    anchor = next((a for a in cfg.uwb_anchors if a.id == fix.anchor), None)
    if anchor is None:
        known = ", ".join(a.id for a in cfg.uwb_anchors) or "none configured"
        raise FixRejected("unknown_reference", f"UWB anchor {fix.anchor!r} is not in the incident config (known: {known})")
    return UwbRange(t=fix.t, anchor_x=anchor.x, anchor_y=anchor.y, range=fix.range, sigma=fix.sigma, anchor=anchor.id)


for _ft in (FixType("checkpoint", _checkpoint), FixType("gnss", _gnss), FixType("uwb", _uwb)):
    register_fix_type(_ft)
