"""Fix types: how a wire ``Fix`` of each source becomes a fix in the incident's local frame.

A fix type is registered under its wire ``source`` name (:func:`register_fix_type`); the
incident core looks it up for every fix message. ``to_domain`` raises :class:`FixRejected`
with a counted reason when the fix cannot be used (an unknown checkpoint or anchor). A domain
fix that depends on the responder's height (a 3D UWB range) has ``at_height(z)``: the core
calls it with the tag's height (the responder's floor elevation + the incident's
``uwb_tag_height_m``). The built-in types live one module each in :mod:`service.fusion.fixes`.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from service.fusion.fixes import ble, checkpoint, gnss, uwb
from service.fusion.fixes.base import FixRejected

__all__ = ["FixRejected", "FixType", "fix_type_of", "register_fix_type"]


@dataclass(frozen=True)
class FixType:
    source: str
    to_domain: Callable  # (wire fix, incident config) -> domain fix with t, factors(ctx)


_TYPES: dict[str, FixType] = {}


def register_fix_type(ft: FixType) -> FixType:
    _TYPES[ft.source] = ft
    return ft


def fix_type_of(source: str) -> FixType:
    try:
        return _TYPES[source]
    except KeyError:
        raise FixRejected("unknown_source", f"no fix type {source!r} is registered (known: {', '.join(_TYPES)})") from None


for _module in (checkpoint, gnss, uwb, ble):
    register_fix_type(FixType(_module.__name__.rsplit(".", 1)[1], _module.to_local))
