"""BLE beacon scans: how strongly the responder's wearable heard beacons at known places.

**Path loss.** The log-distance model with a floor attenuation factor (Seidel & Rappaport,
"914 MHz path loss prediction models for indoor wireless communications in multifloored
buildings", IEEE Trans. Antennas Propag. 40(2), 1992)::

    RSSI = P₀ + δ − 10·n·log₁₀(r / 1 m) − F·|floor − floor_b| + ε,   r = √(Δx² + Δy² + Δz² + r₀²)

``P₀`` the beacon's RSSI at 1 m (its ``tx_power_dbm`` in the incident config, calibrated by
``firetrack eval ble``, else :attr:`BleSettings.tx_power_dbm`), ``n`` the path-loss exponent,
``F`` the loss per floor between responder and beacon, ``r₀`` a near-field floor that keeps the
model finite under the beacon, ``Δz`` from the floors' elevations. ``ε`` (dB) is shadowing:
walls, the walker's own body between phone and beacon, people; it is heavy-tailed and lasts
seconds, so each beacon of a scan is one factor on the position of the scan's time with
``σ = sigma_db`` behind a Cauchy kernel, ρ(u) = w²/2·log(1 + (u/w)²): a reading 30 dB off
(a body, a metal door, a beacon moved) pulls a tenth as hard as a Gaussian would, and the pull
of any reading falls as 1/r with distance (∂RSSI/∂r = −10n / (r ln 10)), so far beacons barely
move the track. Readings weaker than ``min_rssi_dbm`` (the receiver's floor, where RSSI no
longer falls with distance) are dropped.

**Online offsets** ``δ``: one per beacon on this track, a scalar Kalman filter on the residual
at the current estimate, ``ν = RSSI − RSSI(p̂)``, with variance ``σ² + gᵀΣ_p g`` (``g`` the
gradient of RSSI in position, ``Σ_p`` the pose's marginal): it learns the phone's gain and the
beacon's mounting where the track is well known and is left alone where it is not. Residuals
beyond ``offset_gate_db`` (a body, NLOS) are not learnt from. The prior is N(0, offset_sigma_db²).

**Wire** (:class:`service.protocol.fixes.BleFixMessage`): one scan, the beacons heard over
``period`` s ending at ``t`` and the mean RSSI of each; the factor is placed at the scan's
middle, the distance walked in half a scan and the beacon's own position sigma added to the
position noise (as dB through the gradient: ``σ² = sigma_db² + |∇RSSI|²·(blur² + σ_b²)``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from service.fusion.fixes.base import FixContext, FixRejected, finite

LN10 = math.log(10.0)
WALK_SPEED_M_S = 1.4  # m/s, a brisk walk: the blur of a scan's position over its period


@dataclass(frozen=True)
class BleSettings:
    """The path-loss model and its noise (units in the names). ``σ``: the survey check's scatter
    on the IPIN museum (6-9 dB); ``F`` between Seidel & Rappaport's 13 dB for one floor and the
    museum's 10-15 dB; ``n``, the weakest reading used and the kernel chosen by leave-one-route-out
    CV among six points (:data:`service.review.ipin_cv.BLE_GRID`: n 2.2, readings from -75 dBm,
    Huber, chosen for 10 of the 11 held-out routes). The survey check's own fit of n over every
    reading is flatter (1.4-1.8): the far field is mostly multipath, which the cut leaves out."""

    tx_power_dbm: float = -65.0  # dBm at 1 m, for a beacon whose config gives none
    path_loss_exponent: float = 2.2  # n
    sigma_db: float = 7.0  # shadowing 1-sigma per scan and beacon
    floor_loss_db: float = 12.0  # F, per floor between responder and beacon
    near_m: float = 1.0  # r₀
    min_rssi_dbm: float = -75.0  # weaker readings are not used (far field: multipath, no range)
    kernel: str = "huber"
    kernel_width: float = 1.0  # sigmas
    offset_sigma_db: float = 4.0  # prior 1-sigma of a beacon's online offset (0: no online calibration)
    offset_gate_db: float = 15.0  # residuals beyond this are not learnt from

    def __post_init__(self) -> None:
        for name in ("path_loss_exponent", "sigma_db", "near_m", "kernel_width", "offset_gate_db"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"BleSettings.{name} must be a finite number > 0, got {v!r}")
        for name in ("tx_power_dbm", "min_rssi_dbm"):
            finite("BleSettings", **{name: getattr(self, name)})
        if not (self.floor_loss_db >= 0 and self.offset_sigma_db >= 0):
            raise ValueError("BleSettings.floor_loss_db and offset_sigma_db must be >= 0")


@dataclass(frozen=True)
class BeaconReading:
    """One beacon of a scan, in the local frame: at ``(x, y, z)`` m (z: elevation of its floor
    plus its height), on ``floor``, heard at ``rssi`` dBm; ``tx_power`` its RSSI at 1 m (NaN:
    the settings' default); ``sigma`` (m) the 1-sigma of its position (a surveyed beacon, or a
    dropped one placed with the uncertainty of the responder who dropped it)."""

    beacon: str
    x: float
    y: float
    z: float
    floor: int
    rssi: float
    tx_power: float = math.nan
    sigma: float = 0.0


@dataclass(frozen=True)
class BleScan:
    """The beacons heard around time ``t`` (s, device clock; the scan's middle), ``period`` s
    long; ``tag_z`` the wearable's height (m, NaN until :meth:`at_height` sets it)."""

    t: float
    readings: tuple[BeaconReading, ...]
    period: float = 0.0
    tag_z: float = math.nan
    source = "ble"
    display = "hold"

    def __post_init__(self) -> None:
        finite("BleScan", t=self.t, period=self.period)
        if not self.readings:
            raise ValueError("BleScan.readings: a scan needs at least one beacon")
        for r in self.readings:
            finite("BeaconReading", x=r.x, y=r.y, z=r.z, rssi=r.rssi)

    def at_height(self, tag_z: float) -> BleScan:
        """The scan with the wearable's height (m, the datum of the floors' elevations)."""
        return BleScan(self.t, self.readings, self.period, float(tag_z))

    def factors(self, ctx: FixContext):
        from service.fusion.noise import robust

        s = ble_settings(ctx.settings)
        heard = [r for r in self.readings if r.rssi >= s.min_rssi_dbm]
        if not heard:
            return ctx.reject("ble_weak", f"no beacon above {s.min_rssi_dbm:.0f} dBm")
        import gtsam

        blur = math.hypot(ctx.slip, 0.5 * self.period * WALK_SPEED_M_S)
        p, cov = ctx.position_marginal()
        offsets = ctx.state.setdefault("offsets", {})  # beacon -> [mean dB, variance dB²]
        out, residuals = [], {}
        for r in heard:
            model = PathLoss(r, s, ctx.floor, self.tag_z)
            off = offsets.setdefault(r.beacon, [0.0, s.offset_sigma_db ** 2])
            predicted, grad = model.rssi(p, off[0])
            sigma = math.hypot(s.sigma_db, float(np.hypot(*grad)) * math.hypot(blur, r.sigma))
            base = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
            out.append(model.factor(ctx.key, r.rssi - off[0], robust(s.kernel, s.kernel_width, base)))
            nu = r.rssi - predicted
            residuals[r.beacon] = round(nu, 1)
            if s.offset_sigma_db > 0 and abs(nu) < s.offset_gate_db:
                var = sigma * sigma + float(grad @ cov @ grad)  # blas-ok: 2x2
                gain = off[1] / (off[1] + var)
                off[0] += gain * nu
                off[1] *= 1.0 - gain
        ctx.info["ble_residual_db"] = residuals
        return out


class PathLoss:
    """The model above for one reading, on the responder's ``floor`` with the tag at ``tag_z``."""

    def __init__(self, reading: BeaconReading, s: BleSettings, floor: int, tag_z: float):
        self.r, self.s = reading, s
        self.p0 = reading.tx_power if math.isfinite(reading.tx_power) else s.tx_power_dbm
        self.p0 -= s.floor_loss_db * abs(floor - reading.floor)
        dz = (reading.z - tag_z) if math.isfinite(tag_z) else 0.0
        self.near2 = s.near_m ** 2 + dz * dz
        self.k = 10.0 * s.path_loss_exponent

    def rssi(self, p: np.ndarray, offset: float = 0.0) -> tuple[float, np.ndarray]:
        """Expected RSSI (dBm) at ``p`` (x, y) and its gradient (dB/m)."""
        d = np.asarray(p, float)[:2] - np.array([self.r.x, self.r.y])
        r2 = float(d[0] * d[0] + d[1] * d[1]) + self.near2
        return self.p0 + offset - 0.5 * self.k * math.log10(r2), -self.k / LN10 * d / r2

    def factor(self, key: int, rssi: float, noise):
        """A unary factor on pose ``key``: ``e = RSSI(p) − rssi`` (dB), its Jacobian in the pose's
        tangent space ``∂e/∂p · [R 0]`` (gtsam's Pose2 moves its translation in the body frame)."""
        import gtsam

        def error(this, values, jacobians):
            pose = values.atPose2(this.keys()[0])
            predicted, g = self.rssi((pose.x(), pose.y()))
            if jacobians is not None:
                c, s = math.cos(pose.theta()), math.sin(pose.theta())
                jacobians[0] = np.array([[g[0] * c + g[1] * s, -g[0] * s + g[1] * c, 0.0]])
            return np.array([predicted - rssi])

        return gtsam.CustomFactor(noise, [key], error)


def ble_settings(fusion_settings) -> BleSettings:
    """The fusion's BLE settings (:attr:`FusionSettings.ble`), defaults when it has none."""
    s = getattr(fusion_settings, "ble", None)
    return s if s is not None else BleSettings()


def to_local(msg, incident) -> BleScan:
    """The beacons of the scan that the incident config knows, at their surveyed places."""
    elevations = incident.elevations()
    readings, unknown = [], []
    for beacon_id, rssi in zip(msg.beacons, msg.rssi):
        b = incident.beacon(beacon_id)
        if b is None:
            unknown.append(beacon_id)
            continue
        z = elevations.get(b.floor, b.floor * incident.floor_height_m) + b.height_m
        tx = b.tx_power_dbm if b.tx_power_dbm is not None else math.nan
        readings.append(BeaconReading(b.id, float(b.x), float(b.y), float(z), int(b.floor), float(rssi), tx, b.sigma_m))
    if not readings:
        known = ", ".join(b.id for b in incident.beacons[:10]) or "none configured"
        raise FixRejected("unknown_reference", f"no beacon of the scan ({', '.join(unknown[:5])}) is in the "
                                               f"incident config (known: {known})")
    return BleScan(t=msg.t - 0.5 * msg.period, readings=tuple(readings), period=msg.period)
