"""A live Foxglove WebSocket server beside the service (``firetrack serve --foxglove PORT``).

The bridge is one more zenoh subscriber: it takes every responder's poses and statuses off
the incident's keys (``firetrack/{incident}/*/pose`` and ``.../status``), as the console does,
and publishes them through ``foxglove-sdk``'s server (``foxglove.start_server``; Foxglove
connects to ``ws://HOST:PORT``, the ``foxglove.websocket.v1`` protocol). So it sees what left
the service, whichever worker process published it, and never slows the worker down.

Topics and messages are the file export's (:mod:`service.review.foxglove_export`, built by
:mod:`service.review.foxglove_scene`): ``/responders/{id}/live/location``
(``foxglove.LocationFix`` with the pose's covariance), ``/responders/{id}/live/pose``
(``foxglove.PoseInFrame`` in the incident's ENU frame), ``/alarms`` (``foxglove.Log``), and
the building (``/tf``, ``/building``, ``/building/plan/floor_{n}``), sent again to each client
that subscribes to them, since a live server keeps no history.
"""
from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable

import foxglove
import zenoh
from foxglove.channels import (
    FrameTransformsChannel,
    GridChannel,
    LocationFixChannel,
    LogChannel,
    PoseInFrameChannel,
    SceneUpdateChannel,
)

from service.protocol import wire
from service.review import foxglove_scene as fx

log = logging.getLogger("firetrack.foxglove")
STATIC_RESEND_DELAY_S = 0.2  # s after a subscription before the building is sent to it


class FoxgloveLive:
    """``FoxgloveLive(session, incident, port, host).close()``; ``port`` 0 takes a free one (see ``.port``)."""

    def __init__(self, session: zenoh.Session, incident, port: int = 8765, host: str = "127.0.0.1"):
        self.incident, self.host = incident, host
        self._frame = fx.enu_frame(incident.id)
        self._elevation = incident.elevations()
        self._lock = threading.Lock()
        self._channels: dict[str, object] = {}
        self._alarms: dict[str, set[str]] = {}
        self._colors: dict[str, int] = {}
        self.poses = 0  # poses passed on
        self.ctx = foxglove.Context()
        self._static: dict[str, tuple[object, Callable]] = {}  # topic -> (channel, message maker)
        self._static["/tf"] = (FrameTransformsChannel("/tf", context=self.ctx), lambda now: fx.floor_transforms(incident, now))
        self._static["/building"] = (SceneUpdateChannel("/building", context=self.ctx),
                                     lambda now: fx.building_scene(incident, now))
        try:
            grids = fx.plan_grids(incident, 0.0)
        except Exception as e:  # an unreadable plan image: the server runs without the plans
            log.warning("floor plans not sent to Foxglove: %s", e)
            grids = {}
        for floor, grid in grids.items():
            self._static[f"/building/plan/floor_{floor}"] = (GridChannel(f"/building/plan/floor_{floor}", context=self.ctx),
                                                             lambda now, g=grid: g)
        self._alarm_channel = LogChannel("/alarms", context=self.ctx)
        self.server = foxglove.start_server(name=f"firetrack {incident.id}", host=host, port=port, context=self.ctx,
                                            server_listener=_Listener(self))
        self._subs = [session.declare_subscriber(wire.key_all(incident.id, "pose"), self._on_pose),
                      session.declare_subscriber(wire.key_all(incident.id, "status"), self._on_status)]

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def send_static(self, topic: str | None = None) -> None:
        """The building (or one of its topics) to whoever is subscribed now."""
        import time

        now = time.time()
        for name, (channel, make) in self._static.items():
            if topic is None or name == topic:
                channel.log(make(now), log_time=int(now * 1e9))

    def _channel(self, topic: str, kind):
        with self._lock:
            ch = self._channels.get(topic)
            if ch is None:
                ch = self._channels[topic] = kind(topic, context=self.ctx)
            return ch

    def _on_pose(self, sample: zenoh.Sample) -> None:
        try:
            p = wire.decode(sample.payload.to_bytes(), expect=wire.Pose)
            unix = p.utc if p.utc is not None else p.published_at
            rid = p.responder
            with self._lock:
                k = self._colors.setdefault(rid, len(self._colors))
            z = self._elevation.get(p.floor, 0.0)
            ns = int(unix * 1e9)
            fix = fx.location_fix(unix, p.lat, p.lon, self.incident.origin.alt_m + z, p.cov, rid, fx.responder_color(k), rid)
            self._channel(f"/responders/{rid}/live/location", LocationFixChannel).log(fix, log_time=ns)
            pose = fx.pose_in_frame(unix, self._frame, p.x, p.y, z, math.radians(90.0 - p.heading_deg))
            self._channel(f"/responders/{rid}/live/pose", PoseInFrameChannel).log(pose, log_time=ns)
            self.poses += 1
        except Exception as e:  # a bad message must not stop the bridge
            log.warning("pose on %s not passed to Foxglove: %s", sample.key_expr, e)

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            s = wire.decode(sample.payload.to_bytes(), expect=wire.Status)
        except Exception as e:
            log.warning("status on %s not passed to Foxglove: %s", sample.key_expr, e)
            return
        with self._lock:
            before = self._alarms.get(s.responder, set())
            self._alarms[s.responder] = now = set(s.alarms)
        for alarm in sorted(now - before):
            when = s.alarms_since.get(alarm, s.last_heard)
            self._alarm_channel.log(fx.log(when, "warning", f"{s.responder}: {alarm}", s.responder), log_time=int(when * 1e9))
        for alarm in sorted(before - now):
            self._alarm_channel.log(fx.log(s.last_heard, "info", f"{s.responder}: {alarm} ended", s.responder),
                                    log_time=int(s.last_heard * 1e9))

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
        self._subs = []
        self.server.stop()


class _Listener:
    """Sends the building to a client that subscribes to it (a live server keeps no history)."""

    def __init__(self, live: FoxgloveLive):
        self._live = live

    def on_subscribe(self, client, channel) -> None:
        if channel.topic in self._live._static:
            threading.Timer(STATIC_RESEND_DELAY_S, self._live.send_static, args=(channel.topic,)).start()

    def on_unsubscribe(self, client, channel) -> None:
        return None
