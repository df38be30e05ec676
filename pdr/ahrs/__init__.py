"""Orientation (AHRS) filters with one streaming call shape; see :mod:`pdr.ahrs.base`."""
from pdr.ahrs.base import FilterSettings, OrientationFilter, settings_with
from pdr.ahrs.complementary import Complementary, ComplementarySettings
from pdr.ahrs.decoupled import Decoupled, DecoupledSettings
from pdr.ahrs.madgwick import Madgwick, MadgwickSettings
from pdr.ahrs.scf import FSCF, SCF, SCFSettings

FILTERS: dict[str, type[OrientationFilter]] = {f.name: f for f in (Decoupled, FSCF, SCF, Madgwick, Complementary)}
# the filter the commands use unless told otherwise (chosen on BROAD by cross-validation; see decoupled.py)
DEFAULT_FILTER = Decoupled.name


def make_filter(name: str, params: dict | None = None, q0=None, frame: str = "ENU") -> OrientationFilter:
    """A filter by name with its shipped defaults, some replaced by ``params``."""
    try:
        cls = FILTERS[name.lower()]
    except KeyError:
        raise ValueError(f"unknown filter {name!r}; choose one of {', '.join(FILTERS)}") from None
    settings = settings_with(cls.Settings(), params or {})
    return cls(settings, q0=q0, frame=frame)


__all__ = [
    "FILTERS", "DEFAULT_FILTER", "make_filter", "Decoupled", "DecoupledSettings", "OrientationFilter", "FilterSettings", "settings_with",
    "FSCF", "SCF", "SCFSettings", "Madgwick", "MadgwickSettings", "Complementary", "ComplementarySettings",
]
