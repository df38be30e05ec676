"""KML export: Google Earth's gx:Track, read back with an XML parser."""
from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from pdr.floors import FloorElevations
from service.protocol.incident import default_incident
from service.review.kml import GX_NS, KML_NS, to_kml, write_kml

NS = {"k": KML_NS, "gx": GX_NS}


def _tracks(n: int = 200):
    t = 1000.0 + np.cumsum(np.full(n, 0.55))
    t[5] = t[4] + 0.001  # a near-duplicate: thinned, so times still strictly increase
    x, y = 10 * np.cos(t / 20), 8 * np.sin(t / 20)
    floor = np.where(np.arange(n) < n // 2, 0, -1)
    smoothed = {"ff1": {"t": t, "x": x, "y": y, "heading": t * 0.0, "floor": floor, "utc_offset": 1.7e9}}
    live = {"ff1": {"t": t, "x": x + 0.3, "y": y, "heading": t * 0.0, "floor": floor, "unix": t + 1.7e9 + 0.2,
                    "cov_xx": np.ones(n), "cov_xy": np.zeros(n), "cov_yy": np.ones(n)},
            "ff2": {"t": t, "x": -x, "y": y, "heading": t * 0.0, "floor": floor, "unix": t + 1.7e9,
                    "cov_xx": np.ones(n), "cov_xy": np.zeros(n), "cov_yy": np.ones(n)}}
    return smoothed, live


def test_every_placemark_has_a_track_with_a_time_per_point_increasing(tmp_path):
    cfg = default_incident()
    smoothed, live = _tracks()
    path = tmp_path / "tracks.kml"
    skipped = write_kml(smoothed, path, cfg.origin, FloorElevations(cfg.elevations()), live=live)
    assert skipped == []
    root = ET.parse(path).getroot()  # a real XML parser: well-formed, namespaces resolved
    assert root.tag == f"{{{KML_NS}}}kml"
    placemarks = root.findall(".//k:Placemark", NS)
    names = sorted(p.find("k:name", NS).text for p in placemarks)
    assert names == ["ff1 live", "ff1 smoothed", "ff2 live"]
    for pm in placemarks:
        track = pm.find("gx:Track", NS)
        when = [np.datetime64(w.text.rstrip("Z")) for w in track.findall("k:when", NS)]
        coords = np.array([[float(v) for v in c.text.split()] for c in track.findall("gx:coord", NS)])
        floors = [int(v.text) for v in track.findall(".//gx:SimpleArrayData[@name='floor']/gx:value", NS)]
        assert len(when) == len(coords) == len(floors) == 199  # one near-duplicate thinned
        assert all(b > a for a, b in zip(when, when[1:])), pm.find("k:name", NS).text
        x, y, _ = cfg.to_enu(coords[:, 1], coords[:, 0])  # gx:coord is lon lat alt
        assert np.all(np.hypot(x, y) < 15.0)
        assert set(floors) == {0, -1} and set(coords[:, 2]) == {0.0, -3.0}  # the floors' elevations
        assert pm.find("k:styleUrl", NS).text.lstrip("#") in {s.get("id") for s in root.iter(f"{{{KML_NS}}}Style")}
    # the smoothed track's times come from its UTC offset, the live poses' from their own UTC times
    sm = next(p for p in placemarks if p.find("k:name", NS).text == "ff1 smoothed")
    first = sm.find("gx:Track/k:when", NS).text
    assert first == str(np.datetime64(int(round((smoothed["ff1"]["t"][0] + 1.7e9) * 1000)), "ms")) + "Z"


def test_a_track_without_a_utc_time_is_left_out_and_named():
    cfg = default_incident()
    smoothed, _ = _tracks()
    smoothed["ff1"]["utc_offset"] = None
    text, skipped = to_kml(smoothed, cfg.origin)
    assert skipped == ["ff1 (smoothed)"]
    assert ET.fromstring(text).findall(".//k:Placemark", NS) == []


def test_bad_tracks_are_named():
    cfg = default_incident()
    smoothed, _ = _tracks()
    smoothed["ff1"]["x"] = smoothed["ff1"]["x"][:-1]
    with pytest.raises(ValueError, match="ff1 \\(smoothed\\)"):
        to_kml(smoothed, cfg.origin)
