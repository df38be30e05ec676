"""An incident's review as an MCAP file that Foxglove opens with nothing to configure.

``firetrack reprocess REC --export DIR`` writes ``DIR/foxglove.mcap`` with the official
``foxglove-sdk`` writer (protobuf messages, each channel with its Foxglove schema); the
message builders are :mod:`service.review.foxglove_scene`. Topics:

========================================  =========================  ===========================================
topic                                     schema                     what
========================================  =========================  ===========================================
``/responders/{id}/live/location``        ``foxglove.LocationFix``   each pose as the service published it, with its covariance (Map panel)
``/responders/{id}/live/pose``            ``foxglove.PoseInFrame``   the same in the incident's ENU frame (3D panel)
``/responders/{id}/smoothed/location``    ``foxglove.LocationFix``   the smoother's track in hindsight (no covariance kept)
``/responders/{id}/smoothed/pose``        ``foxglove.PoseInFrame``   the same in the ENU frame
``/responders/{id}/smoothed/path``        ``foxglove.PosesInFrame``  the whole smoothed track, once, at its start
``/tf``                                   ``foxglove.FrameTransforms`` ENU frame -> each floor's frame (its elevation)
``/building``                             ``foxglove.SceneUpdate``   floors' outlines and names, checkpoints, anchors, beacons
``/building/plan/floor_{n}``              ``foxglove.Grid``          floor n's plan image
``/alarms``                               ``foxglove.Log``           alarms as they began and ended (from the Status messages)
``/operator``                             ``foxglove.Log``           operator actions and the service's verdicts (the Audits)
========================================  =========================  ===========================================

The recorder's own recording is untouched: this is a second file beside the other exports.
Times are UTC: a live pose at its ``utc`` (the device time placed by the wearable's clock
offset; the service's publication time when the wearable sent none), the smoothed track at
device time + the responder's UTC offset; the building at the first of these.
"""
from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np

from service.review import foxglove_scene as fx


def write_foxglove_mcap(path: str | os.PathLike, incident, live: Mapping[str, Mapping], smoothed: Mapping[str, Mapping],
                        events: list[dict] = ()) -> dict[str, int]:
    """Write the MCAP; returns the number of messages per topic.

    ``live``: per responder the published poses as columns ``unix`` (UTC s), ``t``, ``x``,
    ``y``, ``floor``, ``heading`` (rad, CCW from East), ``cov_xx``, ``cov_xy``, ``cov_yy``.
    ``smoothed``: per responder ``t``, ``x``, ``y``, ``floor``, ``heading`` and ``utc_offset``
    (s, None: taken from the live poses). ``events``: dicts with ``unix``, ``topic``
    (``alarms`` or ``operator``), ``level``, ``name``, ``message``.
    """
    import foxglove
    from foxglove.channels import (
        FrameTransformsChannel,
        GridChannel,
        LocationFixChannel,
        LogChannel,
        PoseInFrameChannel,
        PosesInFrameChannel,
        SceneUpdateChannel,
    )

    elevation = incident.elevations()
    frame = fx.enu_frame(incident.id)
    items: list[tuple[int, int, str, object]] = []  # (log time ns, order, topic, message)

    def add(unix: float, topic: str, msg) -> None:
        items.append((int(round(unix * 1e9)), len(items), topic, msg))

    rids = sorted(set(live) | set(smoothed))
    for k, rid in enumerate(rids):
        color = fx.responder_color(k)
        tr = live.get(rid)
        if tr is not None and len(tr["t"]):
            lat, lon, alt = _geodetic(incident, tr, elevation)
            for i in range(len(tr["t"])):
                u = float(tr["unix"][i])
                cov = np.array([[tr["cov_xx"][i], tr["cov_xy"][i]], [tr["cov_xy"][i], tr["cov_yy"][i]]])
                add(u, f"/responders/{rid}/live/location", fx.location_fix(u, lat[i], lon[i], alt[i], cov, rid, color, rid))
                add(u, f"/responders/{rid}/live/pose", fx.pose_in_frame(u, frame, tr["x"][i], tr["y"][i],
                                                                         elevation[int(tr["floor"][i])], tr["heading"][i]))
        sm = smoothed.get(rid)
        offset = _utc_offset(sm, tr)
        if sm is not None and len(sm["t"]) and offset is not None:
            lat, lon, alt = _geodetic(incident, sm, elevation)
            unix = np.asarray(sm["t"], dtype=np.float64) + offset
            z = np.array([elevation[int(f)] for f in sm["floor"]])
            for i in range(len(unix)):
                add(unix[i], f"/responders/{rid}/smoothed/location",
                    fx.location_fix(unix[i], lat[i], lon[i], alt[i], None, rid, fx.responder_color(k, 0.6), rid))
                add(unix[i], f"/responders/{rid}/smoothed/pose",
                    fx.pose_in_frame(unix[i], frame, sm["x"][i], sm["y"][i], z[i], sm["heading"][i]))
            add(unix[0], f"/responders/{rid}/smoothed/path",
                fx.path_in_frame(unix[0], frame, sm["x"], sm["y"], z, sm["heading"]))
    for e in events:
        add(e["unix"], f"/{e['topic']}", fx.log(e["unix"], e["level"], e["message"], e["name"]))
    t0 = min((it[0] for it in items), default=None)
    start = t0 / 1e9 if t0 is not None else 0.0
    add(start, "/tf", fx.floor_transforms(incident, start))
    add(start, "/building", fx.building_scene(incident, start))
    for floor, grid in fx.plan_grids(incident, start).items():
        add(start, f"/building/plan/floor_{floor}", grid)
    items.sort(key=lambda it: (it[0], it[1]))

    kinds = {"LocationFix": LocationFixChannel, "PoseInFrame": PoseInFrameChannel, "PosesInFrame": PosesInFrameChannel,
             "FrameTransforms": FrameTransformsChannel, "SceneUpdate": SceneUpdateChannel, "Grid": GridChannel,
             "Log": LogChannel}
    ctx = foxglove.Context()
    counts: dict[str, int] = {}
    with foxglove.open_mcap(path, allow_overwrite=True, context=ctx) as writer:
        writer.write_metadata("firetrack", {"incident": incident.id, "name": incident.name or "",
                                            "origin": f"{incident.origin.lat},{incident.origin.lon},{incident.origin.alt_m}",
                                            "frame": frame})
        channels: dict[str, object] = {}
        for ns, _, topic, msg in items:
            ch = channels.get(topic)
            if ch is None:
                ch = channels[topic] = kinds[type(msg).__name__](topic, context=ctx)
            ch.log(msg, log_time=ns)
            counts[topic] = counts.get(topic, 0) + 1
    return counts


def _geodetic(incident, track: Mapping, elevation: dict[int, float]):
    up = np.array([elevation[int(f)] for f in track["floor"]], dtype=np.float64)
    lat, lon, alt = incident.to_geodetic(np.asarray(track["x"], dtype=np.float64), np.asarray(track["y"], dtype=np.float64), up)
    return np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(alt)


def _utc_offset(smoothed: Mapping | None, live: Mapping | None) -> float | None:
    """UTC minus device time of a responder: the smoothed track's own, else its live poses'."""
    if smoothed is not None and smoothed.get("utc_offset") is not None:
        return float(smoothed["utc_offset"])
    if live is not None and len(live["t"]):
        return float(np.median(np.asarray(live["unix"]) - np.asarray(live["t"])))
    return None
