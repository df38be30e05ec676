"""Export smoothed tracks for other tools: GeoJSON (maps), CSV (spreadsheets), TUM (evo).

A track is a mapping of equal-length arrays, the service's smoothed estimate of one responder:

- ``t`` — s, device clock, increasing
- ``x``, ``y`` — m, East and North in the incident's local ENU frame
- ``heading`` — rad, yaw of the body, counter-clockwise from East (gtsam Pose2's theta)
- ``floor`` — integer floor number

Geodetic coordinates come from the incident origin (``lat``, ``lon`` in degrees, ``alt`` in m
above the WGS84 ellipsoid) with ``pymap3d.enu2geodetic``; the up coordinate is the floor's
elevation when a :class:`pdr.floors.FloorElevations` is given (elevations taken as metres
above the origin), else 0. What a person reads is the compass bearing (clockwise from North,
degrees), so that is what the CSV and GeoJSON carry; TUM carries the quaternion.
"""
from __future__ import annotations

import csv
import io
import math
import os
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import pymap3d

from pdr.events import bearing_deg
from pdr.floors import FloorElevations

COORD_DECIMALS = 7  # degrees: 1e-7 deg is ~1.1 cm at the equator, finer than any track here


class IncidentOrigin(NamedTuple):
    """Where the incident's ENU frame is anchored: WGS84 latitude, longitude (deg), height (m)."""

    lat: float
    lon: float
    alt: float = 0.0


def _origin(origin) -> IncidentOrigin:
    if isinstance(origin, Mapping):
        o = IncidentOrigin(float(origin["lat"]), float(origin["lon"]), float(origin.get("alt", origin.get("alt_m", 0.0))))
    elif hasattr(origin, "lat") and hasattr(origin, "lon"):  # IncidentOrigin, or the incident config's Origin (alt_m)
        o = IncidentOrigin(float(origin.lat), float(origin.lon), float(getattr(origin, "alt", getattr(origin, "alt_m", 0.0))))
    else:
        o = IncidentOrigin(*(float(v) for v in origin))
    if not (-90 <= o.lat <= 90 and -180 <= o.lon <= 180 and math.isfinite(o.alt)):
        raise ValueError(f"incident origin {o} is not a WGS84 position (lat in [-90, 90], lon in [-180, 180])")
    return o


def _track_arrays(track: Mapping, name: str) -> dict[str, np.ndarray]:
    """The track's columns as arrays, checked: same length, finite, time increasing."""
    missing = [k for k in ("t", "x", "y", "heading", "floor") if k not in track]
    if missing:
        raise ValueError(f"track {name!r} has no {', '.join(missing)} (needs t, x, y, heading, floor)")
    cols = {k: np.asarray(track[k], dtype=np.float64).ravel() for k in ("t", "x", "y", "heading")}
    floor = np.asarray(track["floor"]).ravel()
    n = len(cols["t"])
    for k, v in [*cols.items(), ("floor", floor)]:
        if len(v) != n:
            raise ValueError(f"track {name!r}: {k} has {len(v)} samples, t has {n}")
        bad = ~np.isfinite(v.astype(np.float64))
        if bad.any():
            raise ValueError(f"track {name!r}: {k} is not finite at sample {int(np.argmax(bad))}")
    if n and np.any(floor.astype(np.float64) != np.round(floor.astype(np.float64))):
        raise ValueError(f"track {name!r}: floor must hold integers")
    if n > 1 and np.any(np.diff(cols["t"]) <= 0):
        raise ValueError(f"track {name!r}: t must increase, it does not at sample {int(np.argmax(np.diff(cols['t']) <= 0)) + 1}")
    cols["floor"] = floor.astype(np.int64)
    return cols


def _up(floor: np.ndarray, floors: FloorElevations | None) -> np.ndarray:
    if floors is None:
        return np.zeros(len(floor))
    known = floors.floors
    idx = np.searchsorted(known, floor)
    bad = (idx >= len(known)) | (known[np.minimum(idx, len(known) - 1)] != floor)
    if bad.any():
        raise ValueError(f"floor {int(floor[np.argmax(bad)])} is not configured; floors: {known.tolist()}")
    return floors.heights[idx]


def _geodetic(c: dict, origin: IncidentOrigin, floors) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    up = _up(c["floor"], floors)
    lat, lon, alt = pymap3d.enu2geodetic(c["x"], c["y"], up, origin.lat, origin.lon, origin.alt)
    return np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64), np.asarray(alt, dtype=np.float64)


# ------------------------------------------------------------------------------------------
# GeoJSON (RFC 7946)
# ------------------------------------------------------------------------------------------
def to_geojson(tracks: Mapping[str, Mapping], origin, floors: FloorElevations | None = None) -> dict:
    """A FeatureCollection with one Feature per responder per stretch on one floor.

    A stretch of two or more samples is a LineString, a lone sample (a floor visited for one
    estimate) a Point; positions are ``[lon, lat]`` in degrees (RFC 7946 §3.1.1, longitude
    first) rounded to :data:`COORD_DECIMALS`. Each feature's properties: ``responder``,
    ``floor``, ``elevation_m`` (if floors are given), ``t_start``, ``t_end`` (s, device clock),
    ``bearing_deg_end`` (compass bearing at the stretch's last sample).
    """
    o = _origin(origin)
    features = []
    for responder, track in tracks.items():
        c = _track_arrays(track, responder)
        if not len(c["t"]):
            continue
        lat, lon, _ = _geodetic(c, o, floors)
        lon = np.round(lon, COORD_DECIMALS)
        lat = np.round(lat, COORD_DECIMALS)
        bearing = bearing_deg(c["heading"])
        cuts = np.flatnonzero(np.diff(c["floor"])) + 1
        for seg in np.split(np.arange(len(c["t"])), cuts):
            a, b = int(seg[0]), int(seg[-1])
            coords = np.column_stack([lon[seg], lat[seg]]).tolist()
            geometry = {"type": "LineString", "coordinates": coords} if len(seg) > 1 else {"type": "Point", "coordinates": coords[0]}
            props = {
                "responder": str(responder),
                "floor": int(c["floor"][a]),
                "t_start": float(c["t"][a]),
                "t_end": float(c["t"][b]),
                "bearing_deg_end": round(float(bearing[b]), 1),
            }
            if floors is not None:
                props["elevation_m"] = floors.elevation(int(c["floor"][a]))
            features.append({"type": "Feature", "geometry": geometry, "properties": props})
    return {"type": "FeatureCollection", "features": features}


# ------------------------------------------------------------------------------------------
# CSV
# ------------------------------------------------------------------------------------------
CSV_COLUMNS = ("responder", "t", "x", "y", "floor", "heading_deg", "lat", "lon")


def to_csv(tracks: Mapping[str, Mapping], path: str | os.PathLike, origin=None,
           floors: FloorElevations | None = None) -> int:
    """One row per sample: ``responder,t,x,y,floor,heading_deg,lat,lon``; returns the row count.

    ``heading_deg`` is the compass bearing (CW from North); ``lat``/``lon`` are empty when no
    origin is given. Times to the microsecond, positions to the millimetre.
    """
    o = None if origin is None else _origin(origin)
    rows = 0
    with open(path, "w", newline="", encoding="utf-8") as f:
        f.write(",".join(CSV_COLUMNS) + "\n")
        for responder, track in tracks.items():
            c = _track_arrays(track, responder)
            n = len(c["t"])
            if not n:
                continue
            if o is not None:
                lat, lon, _ = _geodetic(c, o, floors)
                geo = np.char.add(np.char.add(np.char.mod("%.8f", lat), ","), np.char.mod("%.8f", lon))
            else:
                geo = np.full(n, ",")
            name = io.StringIO()
            csv.writer(name, lineterminator="").writerow([responder])  # quoted if it needs to be
            body = np.char.add(np.char.add(np.char.mod("%.6f", c["t"]), ","), np.char.mod("%.3f", c["x"]))
            body = np.char.add(np.char.add(body, ","), np.char.mod("%.3f", c["y"]))
            body = np.char.add(np.char.add(body, ","), c["floor"].astype(str))
            body = np.char.add(np.char.add(body, ","), np.char.mod("%.2f", bearing_deg(c["heading"])))
            lines = np.char.add(np.char.add(np.char.add(name.getvalue() + ",", body), ","), geo)
            f.write("\n".join(lines.tolist()) + "\n")
            rows += n
    return rows


# ------------------------------------------------------------------------------------------
# TUM (evo's trajectory format)
# ------------------------------------------------------------------------------------------
def yaw_quaternion_xyzw(yaw: np.ndarray) -> np.ndarray:
    """Rotation by ``yaw`` about the up axis, body -> ENU, Hamilton, as (N, 4) ``qx qy qz qw``.

    q = (cos(yaw/2), 0, 0, sin(yaw/2)) scalar-first; TUM puts the scalar last.
    """
    half = 0.5 * np.asarray(yaw, dtype=np.float64)
    z = np.zeros_like(half)
    return np.column_stack([z, z, np.sin(half), np.cos(half)])


def to_tum(track: Mapping, path: str | os.PathLike, floors: FloorElevations | None = None) -> int:
    """Write ``t x y z qx qy qz qw`` per line (TUM RGB-D format, read by ``evo``); returns lines.

    z is the floor's elevation when ``floors`` is given, else 0; the orientation is the yaw
    alone (the smoothed track carries no tilt).
    """
    c = _track_arrays(track, "track")
    z = _up(c["floor"], floors)
    table = np.column_stack([c["t"], c["x"], c["y"], z, yaw_quaternion_xyzw(c["heading"])])
    np.savetxt(path, table, fmt=["%.6f", "%.4f", "%.4f", "%.4f", "%.9f", "%.9f", "%.9f", "%.9f"], delimiter=" ")
    return len(table)


__all__ = ["CSV_COLUMNS", "IncidentOrigin", "bearing_deg", "to_csv", "to_geojson", "to_tum", "yaw_quaternion_xyzw"]
