"""The one call shape every orientation filter shares.

``f = SomeFilter(settings, q0=None, frame="ENU")`` then, for each batch of samples,
``q = f.update(t, acc, gyr, mag=None)`` returns the orientation after every sample,
shape (N, 4), scalar first, rotating body -> ``frame``. Without ``mag`` the filter
takes its IMU-only path. ``SomeFilter.run(t, acc, gyr, mag, q0=...)`` is the batch form.

Streaming: the state is the quaternion and the time of the last sample, so feeding a
recording in batches of any size gives the same answer as one batch (the kernel sees
the same ``dt`` sequence). The first sample a filter ever sees sets its clock; the
output there is ``q0`` if given, else the orientation of the first accelerometer (and
magnetometer) sample. Intervals are clipped to ``[0, max_dt]`` so a gap or a repeated
timestamp cannot spin the state.

Frames: the kernels run in the papers' native frame, x towards magnetic north, z up
(``"NWU"``); ``frame="ENU"`` turns that by +90° about z, so the output's y points north.
"""
from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

from pdr import quaternion as quat
from pdr.settings import settings_with  # noqa: F401  (re-exported)

# q_ENU<-NWU: rotation by +90° about z (NWU x = north becomes ENU y)
_NWU_TO_ENU = quat.from_yaw(np.pi / 2)
_ENU_TO_NWU = quat.conjugate(_NWU_TO_ENU)
FRAMES = ("ENU", "NWU")


@dataclasses.dataclass(frozen=True)
class FilterSettings:
    """Settings shared by every filter; subclasses add their gains (each with a unit)."""

    max_dt: float = 0.5  # s; longer intervals are treated as this long


class OrientationFilter:
    """Base of the streaming filters; subclasses set ``name``, ``Settings`` and ``_kernel``."""

    name: ClassVar[str] = ""
    Settings: ClassVar[type[FilterSettings]] = FilterSettings

    def __init__(self, settings: FilterSettings | None = None, q0: np.ndarray | None = None, frame: str = "ENU"):
        if frame not in FRAMES:
            raise ValueError(f"unknown frame {frame!r}; expected one of {FRAMES}")
        self.settings = settings if settings is not None else self.Settings()
        self.frame = frame
        self._q_native: np.ndarray | None = None if q0 is None else self._to_native(np.asarray(q0, float))
        self._t_last: float | None = None

    # -- frame conversion -------------------------------------------------------------
    def _to_native(self, q: np.ndarray) -> np.ndarray:
        q = quat.normalize(q)
        # Hamilton product written out element by element, not a matmul: a BLAS kernel
        # would sum in an order that depends on the batch's shape and the CPU.
        return q if self.frame == "NWU" else quat.multiply(_ENU_TO_NWU, q)

    def _from_native(self, q: np.ndarray) -> np.ndarray:
        return q if self.frame == "NWU" else quat.multiply(_NWU_TO_ENU, q)

    @property
    def q(self) -> np.ndarray | None:
        """The current orientation (body -> frame), or None before the first sample."""
        return None if self._q_native is None else self._from_native(self._q_native)

    # -- streaming --------------------------------------------------------------------
    def update(self, t, acc, gyr, mag=None) -> np.ndarray:
        t = np.ascontiguousarray(t, dtype=np.float64).reshape(-1)
        acc = _as_n3(acc, "acc", t.shape[0])
        gyr = _as_n3(gyr, "gyr", t.shape[0])
        use_mag = mag is not None
        mag = _as_n3(mag, "mag", t.shape[0]) if use_mag else np.zeros((t.shape[0], 3))
        n = t.shape[0]
        if n == 0:
            return np.empty((0, 4))
        out = np.empty((n, 4))
        start = 0
        if self._t_last is None:
            if self._q_native is None:
                self._q_native = quat.from_two_vectors(acc[0], mag[0] if use_mag else None, north_axis=0)
            out[0] = self._q_native
            self._t_last = float(t[0])
            start = 1
        if start < n:
            dt = np.diff(t[start - 1 :] if start else np.concatenate([[self._t_last], t]))
            np.clip(dt, 0.0, self.settings.max_dt, out=dt)
            q = self._kernel(self._q_native, dt, acc[start:], gyr[start:], mag[start:], use_mag)
            out[start:] = q
            self._q_native = q[-1].copy()
            self._t_last = float(t[-1])
        return self._from_native(out)

    def _kernel(self, q0, dt, acc, gyr, mag, use_mag) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    @classmethod
    def run(cls, t, acc, gyr, mag=None, q0=None, settings=None, frame="ENU") -> np.ndarray:
        """Batch form: a fresh filter over a whole recording."""
        return cls(settings, q0=q0, frame=frame).update(t, acc, gyr, mag)


def _as_n3(a, name: str, n: int) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    if a.shape != (n, 3):
        raise ValueError(f"{name} must have shape ({n}, 3), got {a.shape}")
    return a
