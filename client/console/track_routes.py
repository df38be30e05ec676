"""The console's track routes: a responder's smoothed track, or everyone's, for the review slider.

A collaborator of :class:`client.console.server.ConsoleServer`, given its zenoh session and
incident id. The tracks come from the service's
``firetrack/{incident}/{responder}/track`` queryables (one wildcard query for all), in the
reply format of :func:`service.protocol.wire.decode_track`; the blocking query runs in an
executor, bounded by :data:`TRACK_QUERY_TIMEOUT_S`.
"""
from __future__ import annotations

import asyncio
import logging

import numpy as np
import zenoh
from aiohttp import web

from client.console.requests import error_response
from pdr.events import bearing_deg
from service.protocol import wire
from service.protocol.wire import decode_track

log = logging.getLogger("firetrack.console")

TRACK_QUERY_TIMEOUT_S = 5.0


class TrackRoutes:
    """``GET /api/track/{responder}`` and ``GET /api/tracks``."""

    def __init__(self, session: zenoh.Session, incident_id: str):
        self.session, self.incident_id = session, incident_id

    def add_routes(self, router: web.UrlDispatcher) -> None:
        router.add_get("/api/tracks", self._tracks)
        router.add_get("/api/track/{responder}", self._track)

    def _query_tracks(self, key: str) -> dict[str, dict]:
        """Blocking zenoh query (run in an executor): responder -> track as JSON-ready lists."""
        out = {}
        for reply in self.session.get(key, timeout=TRACK_QUERY_TIMEOUT_S):
            if reply.ok is None:
                log.warning("track query %s: %s", key, reply.err.payload.to_string())
                continue
            d = decode_track(reply.ok.payload.to_bytes())
            yaw = d["heading"]  # ENU yaw, rad (gtsam theta); NaN on dead-reckoning tracks
            bearing = bearing_deg(yaw)
            out[str(d["responder"])] = {
                "responder": str(d["responder"]), "smoothed": bool(d["smoothed"]),
                "t": d["t"].tolist(), "x": np.round(d["x"], 3).tolist(), "y": np.round(d["y"], 3).tolist(),
                "floor": d["floor"].astype(int).tolist(),
                "heading_deg": np.where(np.isfinite(bearing), np.round(bearing, 1), None).tolist(),
            }
        return out

    async def _track(self, request: web.Request) -> web.Response:
        rid = request.match_info["responder"]
        if not wire.is_valid_id(rid):
            return error_response(400, f"responder id {rid!r} must match [A-Za-z0-9_.-]{{1,64}}")
        tracks = await asyncio.get_running_loop().run_in_executor(
            None, self._query_tracks, wire.key(self.incident_id, rid, "track"))
        if rid not in tracks:
            return error_response(404, f"no track of responder {rid!r}: the service of incident {self.incident_id!r} "
                               f"did not answer within {TRACK_QUERY_TIMEOUT_S:g} s or does not know {rid!r}")
        return web.json_response(tracks[rid])

    async def _tracks(self, request: web.Request) -> web.Response:
        tracks = await asyncio.get_running_loop().run_in_executor(
            None, self._query_tracks, wire.key_all(self.incident_id, "track"))
        return web.json_response({"tracks": tracks})
