"""What every fix type shares: its checks, and the context its factors are built in.

A fix type is one module (:mod:`.checkpoint`, :mod:`.gnss`, :mod:`.uwb`, or one of your own):

* a **domain fix**, a frozen dataclass in the incident's local ENU frame (m) on the device
  clock (s), that checks itself when built (``ValueError`` naming the field), with
  ``factors(ctx) -> [gtsam factors] | None`` and ``display`` (``"snap"``: the published pose
  shows the new estimate at once; ``"hold"``: it moves there over the next steps);
* ``to_local(message, incident)``: the wire message (:mod:`service.protocol.fixes`) to the
  domain fix, raising :class:`FixRejected` with a counted reason when it cannot be used;
* one registration with the incident core (:func:`service.core.fix_types.register_fix_type`).
"""
from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass, field


class FixRejected(ValueError):
    """A fix that cannot be used; ``reason`` is its Status counter name (``fix_<reason>``)."""

    def __init__(self, reason: str, detail: str):
        super().__init__(detail)
        self.reason = reason


def finite(owner: str, **values: float) -> None:
    for name, v in values.items():
        if not isinstance(v, numbers.Real) or not math.isfinite(v):
            raise ValueError(f"{owner}.{name} must be a finite number, got {v!r}")


def positive(owner: str, **values: float) -> None:
    for name, v in values.items():
        if not isinstance(v, numbers.Real) or math.isnan(v) or v <= 0.0:
            raise ValueError(f"{owner}.{name} must be > 0, got {v!r}")


@dataclass
class FixContext:
    """What ``factors(ctx)`` may use, for the pose nearest the fix's time.

    ``key`` is that pose's gtsam key and ``floor`` its floor; ``slip`` the distance walked
    between the pose and the fix (m: add it to the sigma, it is interpolation noise);
    ``settings`` the fusion's; ``position_marginal()`` the pose's (x, y) estimate and ENU 2x2
    covariance (for a gate); ``anchor(id, x, y)`` the key of a surveyed point's variable (new
    ones get a tight prior); ``state`` a dict the fusion keeps per fix source for this track
    (e.g. the time of the last factor); ``info`` what to log with the decision;
    ``reject(reason, detail)`` refuses the fix.
    """

    key: int
    floor: int
    slip: float
    settings: object
    position_marginal: Callable
    anchor: Callable
    state: dict
    info: dict = field(default_factory=dict)
    rejected: tuple[str, str] | None = None

    def reject(self, reason: str, detail: str = "") -> None:
        self.rejected = (reason, detail)
