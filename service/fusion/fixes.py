"""Absolute position information that corrects a responder's dead-reckoned track.

These are domain objects, not wire messages: the service converts a wire ``Fix`` into one
of them (GNSS latitude/longitude to local ENU metres with pymap3d, anchor names to surveyed
anchor positions) before handing it to :class:`service.fusion.graph.TrackFusion`.

All positions are in the incident's local ENU frame (m), times on the responder's device
clock (s). Each fix checks itself when built and raises ``ValueError`` naming the field, so
a malformed fix is reported where it was made instead of poisoning the factor graph.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass


def _finite(owner: str, **values: float) -> None:
    for name, v in values.items():
        if not isinstance(v, numbers.Real) or not math.isfinite(v):
            raise ValueError(f"{owner}.{name} must be a finite number, got {v!r}")


def _positive(owner: str, **values: float) -> None:
    for name, v in values.items():
        if not isinstance(v, numbers.Real) or math.isnan(v) or v <= 0.0:
            raise ValueError(f"{owner}.{name} must be > 0, got {v!r}")


@dataclass(frozen=True)
class CheckpointFix:
    """The responder was at a surveyed point ``(x, y)`` (m) at time ``t`` (s).

    Reported by the responder or an operator ("at stairwell B, floor 2"), so it is trusted:
    no outlier gate, a Gaussian prior with ``sigma`` (m, 1-sigma per axis). ``floor`` (when
    given) relabels the track's floor from this pose on. The seeds' checkpoint correction
    resets the position to the checkpoint (seed 002 §2.10); here it is a prior in the factor
    graph, so it also straightens the history walked before it.
    """

    t: float
    x: float
    y: float
    floor: int | None = None
    sigma: float = 0.5
    name: str | None = None

    def __post_init__(self) -> None:
        _finite("CheckpointFix", t=self.t, x=self.x, y=self.y)
        _positive("CheckpointFix", sigma=self.sigma)
        if self.floor is not None and not isinstance(self.floor, numbers.Integral):
            raise ValueError(f"CheckpointFix.floor must be an int or None, got {self.floor!r}")


@dataclass(frozen=True)
class GnssFix:
    """A satellite position already converted to local ENU ``(x, y)`` (m).

    ``accuracy`` is the receiver's horizontal 1-sigma (m); ``inf`` is allowed and simply fails
    the accuracy gate. Near and inside buildings GNSS suffers multipath, so the fusion gates
    and down-weights it.
    """

    t: float
    x: float
    y: float
    accuracy: float

    def __post_init__(self) -> None:
        _finite("GnssFix", t=self.t, x=self.x, y=self.y)
        _positive("GnssFix", accuracy=self.accuracy)


@dataclass(frozen=True)
class UwbRange:
    """A measured distance ``range`` (m, 1-sigma ``sigma``) to a UWB anchor at a known point.

    ``anchor`` names the anchor (the same name and position reuse one anchor variable in
    the graph). Non-line-of-sight ranges are biased long, hence a robust kernel downstream.
    """

    t: float
    anchor_x: float
    anchor_y: float
    range: float
    sigma: float
    anchor: str = ""
    anchor_z: float = math.nan  # m, the anchor's height; NaN: the range is already horizontal

    def __post_init__(self) -> None:
        _finite("UwbRange", t=self.t, anchor_x=self.anchor_x, anchor_y=self.anchor_y, range=self.range)
        _positive("UwbRange", sigma=self.sigma)
        if self.range < 0.0:
            raise ValueError(f"UwbRange.range must be >= 0, got {self.range!r}")

    def at_height(self, tag_z: float) -> UwbRange:
        """The horizontal distance equivalent to this 3D range, for a tag at height ``tag_z`` (m,
        same datum as ``anchor_z``): ``r_h = √(r² − Δz²)``, ``σ_h = σ·r / r_h`` (first order; a
        range shorter than the height difference, noise, gives ``r_h = 0``). A range that is
        already horizontal (``anchor_z`` NaN) is returned as it is."""
        if not math.isfinite(self.anchor_z):
            return self
        dz = self.anchor_z - tag_z
        r_h = math.sqrt(max(self.range * self.range - dz * dz, 0.0))
        sigma = self.sigma * self.range / max(r_h, self.sigma)
        return dataclasses.replace(self, range=r_h, sigma=max(sigma, self.sigma), anchor_z=math.nan)


Fix = CheckpointFix | GnssFix | UwbRange
