"""One in-memory type for every recording, whatever format it came from.

Loaders in :mod:`pdr.io` convert to SI units (m/s², rad/s, µT, hPa, s) and to this
type; the algorithms never see a file format. Each sensor is its own time series on
the device clock, because phones sample their sensors at different, jittery rates;
:meth:`Recording.imu_samples` puts them on one time base when an algorithm needs that.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Series:
    """Samples of one sensor: ``t`` (N,) seconds on the device clock, ``values`` (N, k)."""

    t: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        if self.t.ndim != 1 or self.values.shape[0] != self.t.shape[0]:
            raise ValueError(f"series shapes disagree: t {self.t.shape}, values {self.values.shape}")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def rate_hz(self) -> float:
        """Median sampling rate (robust to the odd gap)."""
        if len(self) < 2:
            return float("nan")
        return float(1.0 / np.median(np.diff(self.t)))


@dataclass(frozen=True)
class Landmarks:
    """Surveyed points the walker stood on (IPIN ``POSI``), times on the device clock."""

    t: np.ndarray  # (M,) s
    lat: np.ndarray  # (M,) deg
    lon: np.ndarray  # (M,) deg
    floor: np.ndarray  # (M,) int
    counter: np.ndarray  # (M,) int, the logger's landmark number

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True)
class GnssFixes:
    """GNSS positions; times on the device clock (converted from the app clock)."""

    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    alt: np.ndarray
    accuracy_m: np.ndarray

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True)
class BeaconReadings:
    """Received signal strengths of radio beacons (BLE advertisements), one row per reading.

    ``t`` (N,) s on the device clock; ``beacon`` (N,) str, the beacon's identity as the scanner
    saw it (a MAC address, or ``uuid:major:minor``); ``rssi`` (N,) dBm; ``tx_power`` (N,) dBm,
    the beacon's advertised power at 1 m (NaN when it does not say).
    """

    t: np.ndarray
    beacon: np.ndarray
    rssi: np.ndarray
    tx_power: np.ndarray

    def __post_init__(self) -> None:
        n = self.t.shape[0]
        if any(a.shape != (n,) for a in (self.t, self.beacon, self.rssi, self.tx_power)):
            raise ValueError("beacon readings: t, beacon, rssi and tx_power must be 1-D of one length")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def ids(self) -> list[str]:
        """The beacons heard, sorted."""
        return sorted(set(self.beacon.tolist()))


@dataclass(frozen=True)
class ImuSamples:
    """IMU samples on one common time base (the accelerometer's)."""

    t: np.ndarray  # (N,)
    acc: np.ndarray  # (N, 3) m/s²
    gyr: np.ndarray  # (N, 3) rad/s
    mag: np.ndarray | None  # (N, 3) µT (or unit vectors where the source is normalised)
    pressure: np.ndarray | None  # (N,) hPa


@dataclass
class Recording:
    """A recording of one person or device, with whatever ground truth its format has.

    ``frame`` names the navigation frame of the orientation reference (``"ENU"``, or
    ``"NWU"`` where x points to magnetic north and z up, as in the Vicon AHRS set).
    """

    source: str
    kind: str
    acc: Series | None = None
    gyr: Series | None = None
    mag: Series | None = None
    pressure: Series | None = None  # values (N, 1) hPa
    gnss: GnssFixes | None = None
    ble: BeaconReadings | None = None
    landmarks: Landmarks | None = None
    orientation_ref: Series | None = None  # (N, 4) quaternions w,x,y,z, body -> frame
    device_orientation: Series | None = None  # the phone's own estimate, for comparison only
    position_ref: Series | None = None  # (N, 2) or (N, 3) m, e.g. Vicon x, y
    step_count_ref: Series | None = None  # (N, 1) running true step count
    true_steps: int | None = None
    frame: str = "ENU"
    meta: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        s = self.acc if self.acc is not None else self.gyr
        if s is None or len(s) < 2:
            return 0.0
        return float(s.t[-1] - s.t[0])

    def imu_samples(self) -> ImuSamples:
        """Gyroscope, magnetometer and pressure interpolated onto the accelerometer clock.

        Linear interpolation; samples outside a sensor's span hold its end value. This is
        the one place where a multi-rate phone log becomes a single-rate IMU stream.
        """
        if self.acc is None or self.gyr is None:
            raise ValueError(f"{self.source}: needs accelerometer and gyroscope samples")
        t = self.acc.t

        def on_t(s: Series | None) -> np.ndarray | None:
            if s is None or len(s) == 0:
                return None
            return np.column_stack([np.interp(t, s.t, s.values[:, k]) for k in range(s.values.shape[1])])

        pres = on_t(self.pressure)
        return ImuSamples(
            t=t,
            acc=self.acc.values,
            gyr=on_t(self.gyr),
            mag=on_t(self.mag),
            pressure=None if pres is None else pres[:, 0],
        )
