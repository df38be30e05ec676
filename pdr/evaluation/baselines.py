"""Peer filters run beside ours in ``firetrack eval ahrs --baseline NAME`` (never a dependency of pdr).

* ``vqf``: the ``vqf`` package (D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation
  estimation with bias estimation and magnetic disturbance rejection", Information Fusion 91
  (2023) 187-204), the real-time filter with its default parameters: ``quat9D`` with a
  magnetometer, ``quat6D`` without. Install it with ``pip install 'firetrack[eval]'``.

VQF takes one fixed sampling time; a recording with jitter is given its median interval.
VQF's earth frame is ENU (magnetic north along y); outputs are turned into the recording's
frame. It always starts from its own estimate, whichever metric scores it.
"""
from __future__ import annotations

import numpy as np

from pdr import quaternion as quat
from pdr.recording import Recording

BASELINES = ("vqf",)
# q_frame<-ENU for the frames a recording may use (see pdr.ahrs.base)
_FROM_ENU = {"ENU": quat.IDENTITY, "NWU": quat.from_yaw(-np.pi / 2)}


class BaselineUnavailable(RuntimeError):
    """The peer's package is not installed."""


def run_baseline(name: str, recording: Recording, use_mag: bool = True) -> np.ndarray:
    """Quaternions (body -> ``recording.frame``) of baseline ``name`` at every accelerometer sample."""
    if name != "vqf":
        raise ValueError(f"unknown baseline {name!r}; choose one of {', '.join(BASELINES)}")
    try:
        from vqf import VQF
    except ImportError:
        raise BaselineUnavailable("the baseline 'vqf' needs the vqf package: pip install 'firetrack[eval]'") from None
    if recording.frame not in _FROM_ENU:
        raise ValueError(f"{recording.source}: frame {recording.frame!r} is not one of {tuple(_FROM_ENU)}")
    imu = recording.imu_samples()
    ts = float(np.median(np.diff(imu.t)))
    f = VQF(ts)
    gyr = np.ascontiguousarray(imu.gyr, dtype=np.float64)
    acc = np.ascontiguousarray(imu.acc, dtype=np.float64)
    if use_mag and imu.mag is not None:
        q = f.updateBatch(gyr, acc, np.ascontiguousarray(imu.mag, dtype=np.float64))["quat9D"]
    else:
        q = f.updateBatch(gyr, acc)["quat6D"]
    return quat.multiply(_FROM_ENU[recording.frame], q)
