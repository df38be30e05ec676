"""Tracks as KML for Google Earth: a time per point (``gx:Track``), the time slider plays them.

One ``Placemark`` per responder and kind (``live``: the poses as published; ``smoothed``: the
smoother's track in hindsight), each holding a ``gx:Track``: a ``<when>`` (ISO 8601 UTC) and
a ``<gx:coord>`` (``lon lat alt``) per sample, in the same order and as many of each, as the
KML 2.2 extension schema requires (Google's KML reference, ``gx:Track``). The floor of every
sample is in the track's ``ExtendedData`` as a ``gx:SimpleArrayData`` named ``floor`` (one
``gx:value`` per sample, the schema ``firetrack``); the altitude is the floor's elevation
(m above the incident origin) and the track is drawn clamped to the ground, since an indoor
floor has no useful height above the terrain Google Earth knows.

Samples are the export's (:func:`service.review.export._track_arrays`: checked, near-duplicate
times thinned, so times strictly increase). A track whose UTC time is unknown (no offset, no
live pose to take it from) is left out and named in the result.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping

import numpy as np

from pdr.floors import FloorElevations
from service.review.export import COORD_DECIMALS, _geodetic, _origin, _track_arrays, _up, utc_iso

KML_NS = "http://www.opengis.net/kml/2.2"
GX_NS = "http://www.google.com/kml/ext/2.2"
COLORS = ("ff1c1ae3", "ffb87e37", "ff4aaf4d", "ffa34e98", "ff007fff", "ff28569a", "ffbf81f7", "ff666666")  # aabbggrr


def _k(tag: str) -> str:
    return f"{{{KML_NS}}}{tag}"


def _gx(tag: str) -> str:
    return f"{{{GX_NS}}}{tag}"


def to_kml(tracks: Mapping[str, Mapping], origin, floors: FloorElevations | None = None, *,
           live: Mapping[str, Mapping] | None = None, name: str = "firetrack") -> tuple[str, list[str]]:
    """The KML document (text) and the names of tracks left out for want of a UTC time.

    ``tracks``: smoothed tracks (``t``, ``x``, ``y``, ``heading``, ``floor``, ``utc_offset``);
    ``live``: the published poses (the same columns, ``unix`` optional: when given it is the
    UTC time of each pose).
    """
    o = _origin(origin)
    ET.register_namespace("", KML_NS)
    ET.register_namespace("gx", GX_NS)
    root = ET.Element(_k("kml"))
    doc = ET.SubElement(root, _k("Document"))
    ET.SubElement(doc, _k("name")).text = name
    schema = ET.SubElement(doc, _k("Schema"), id="firetrack")
    field = ET.SubElement(schema, _gx("SimpleArrayField"), name="floor", type="int")
    ET.SubElement(field, _k("displayName")).text = "floor"
    rids = sorted(set(tracks) | set(live or {}))
    for k, rid in enumerate(rids):
        for kind, width in (("live", "2"), ("smoothed", "4")):
            style = ET.SubElement(doc, _k("Style"), id=f"{kind}-{k}")
            line = ET.SubElement(style, _k("LineStyle"))
            color = COLORS[k % len(COLORS)]
            ET.SubElement(line, _k("color")).text = color if kind == "smoothed" else "99" + color[2:]
            ET.SubElement(line, _k("width")).text = width
    skipped = []
    for k, rid in enumerate(rids):
        lv = (live or {}).get(rid)
        for kind, tr in (("live", lv), ("smoothed", tracks.get(rid))):
            if tr is None:
                continue
            c = _track_arrays(tr, f"{rid} ({kind})")
            if not len(c["t"]):
                continue
            when = _when(tr, c, lv)
            if when is None:
                skipped.append(f"{rid} ({kind})")
                continue
            lat, lon, _ = _geodetic(c, o, floors)
            up = _up(c["floor"], floors)
            pm = ET.SubElement(doc, _k("Placemark"))
            ET.SubElement(pm, _k("name")).text = f"{rid} {kind}"
            ET.SubElement(pm, _k("styleUrl")).text = f"#{kind}-{k}"
            track = ET.SubElement(pm, _gx("Track"))
            ET.SubElement(track, _k("altitudeMode")).text = "clampToGround"
            for w in when:
                ET.SubElement(track, _k("when")).text = w
            for a, b, h in zip(np.round(lon, COORD_DECIMALS), np.round(lat, COORD_DECIMALS), up):
                ET.SubElement(track, _gx("coord")).text = f"{a:.{COORD_DECIMALS}f} {b:.{COORD_DECIMALS}f} {h:.2f}"
            data = ET.SubElement(ET.SubElement(track, _k("ExtendedData")), _k("SchemaData"), schemaUrl="#firetrack")
            arr = ET.SubElement(data, _gx("SimpleArrayData"), name="floor")
            for f in c["floor"]:
                ET.SubElement(arr, _gx("value")).text = str(int(f))
    ET.indent(root, space=" ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n", skipped


def _when(track: Mapping, c: dict, live: Mapping | None) -> list[str] | None:
    """ISO 8601 UTC of each kept sample: the track's ``unix`` column, else device time + its
    UTC offset, else + the offset its responder's live poses show (median of unix − t)."""
    if "unix" in track:
        t_all = np.asarray(track["t"], dtype=np.float64).ravel()
        unix = np.asarray(track["unix"], dtype=np.float64).ravel()[np.searchsorted(t_all, c["t"])]
        return utc_iso(unix, 0.0)
    if c["utc_offset"] is not None:
        return utc_iso(c["t"], c["utc_offset"])
    if live is not None and "unix" in live and len(live["t"]):
        return utc_iso(c["t"], float(np.median(np.asarray(live["unix"]) - np.asarray(live["t"]))))
    return None


def write_kml(tracks, path: str | os.PathLike, origin, floors: FloorElevations | None = None, *, live=None,
              name: str = "firetrack") -> list[str]:
    """Write :func:`to_kml`'s document to ``path``; returns the tracks left out."""
    text, skipped = to_kml(tracks, origin, floors, live=live, name=name)
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
    return skipped
