"""What the console knows now: the latest pose and status of every responder, batched for the page.

Zenoh delivers ``.../pose`` and ``.../status`` samples on its own threads; :class:`LiveBoard`
decodes each one (:func:`service.protocol.wire.decode`), keeps the latest per responder and a short
trail of positions, and marks the responder changed. The web server takes the changes every
batch period (:meth:`LiveBoard.take_changes`) and sends them as ONE message to every page, so
200 responders at 2 Hz become about 7 messages a second per page instead of 800.

A payload that does not decode is counted by reason (``rejected``) and logged, at most
:data:`LOG_REJECTS_PER_REASON` lines per reason, never dropped silently; the page shows the
counts. Times: ``t`` is the responder's device clock (s), ``received_at`` the console's wall
clock (unix s) when the sample arrived — the page computes "last heard" and its own
lost-contact alarm from it.
"""
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable

from service.protocol import wire

log = logging.getLogger("firetrack.console")

TRAIL_POINTS = 120  # positions kept per responder for a page that connects later (about 1.5 min of steps)
LOG_REJECTS_PER_REASON = 5


def pose_json(p: wire.Pose, received_at: float) -> dict:
    """A Pose as the page reads it; ``cov`` is ``[xx, xy, yy]`` (m², ENU)."""
    c = p.cov
    return {"responder": p.responder, "t": p.t, "x": round(p.x, 3), "y": round(p.y, 3), "floor": p.floor,
            "heading_deg": round(p.heading_deg, 1), "cov": [float(c[0, 0]), float(c[0, 1]), float(c[1, 1])],
            "steps": p.steps, "source": p.source, "seq": p.seq, "published_at": p.published_at,
            "received_at": received_at}


def status_json(s: wire.Status, received_at: float) -> dict:
    return {"responder": s.responder, "t": s.t, "motion": s.motion, "motion_since": s.motion_since,
            "alarms": list(s.alarms), "alarms_since": dict(s.alarms_since), "rejected": dict(s.rejected),
            "frames": s.frames, "gaps": s.gaps, "lost": s.lost, "gap_s": round(s.gap_s, 2), "streams": s.streams,
            "last_heard": s.last_heard, "steps": s.steps,
            "fixes": dict(s.fixes), "last_fix": s.last_fix, "first_heard": s.first_heard, "utc_offset": s.utc_offset,
            "commands": {a: dict(o) for a, o in s.commands.items()}, "man_down_at": s.man_down_at, "ok_at": s.ok_at,
            "lag_s": s.lag_s, "received_at": received_at}


class LiveBoard:
    """Latest pose/status per responder, a trail each, and the set changed since the last take."""

    def __init__(self, trail_points: int = TRAIL_POINTS, clock: Callable[[], float] = time.time):
        self.clock = clock
        self.trail_points = trail_points
        self._lock = threading.Lock()
        self._pose: dict[str, dict] = {}
        self._status: dict[str, dict] = {}
        self._trail: dict[str, deque] = {}
        self._changed_pose: dict[str, dict] = {}
        self._changed_status: dict[str, dict] = {}
        self.rejected: dict[str, int] = {}
        self.received = {"pose": 0, "status": 0}

    # ------------------------------------------------------------------ zenoh side
    def on_sample(self, kind: str, key: str, payload: bytes) -> None:
        """One ``.../pose`` or ``.../status`` payload from zenoh (any thread)."""
        now = self.clock()
        cls = wire.Pose if kind == "pose" else wire.Status
        try:
            msg = wire.decode(payload, expect=cls)
            _, rid, _ = wire.parse_key(key)
            if msg.responder != rid:
                raise wire.WireError("schema", f"responder {msg.responder!r} in a {kind} on the key of {rid!r}")
        except wire.WireError as e:
            self._reject(e.reason, f"{key}: {e.detail}")
            return
        except ValueError as e:  # a key outside the layout
            self._reject("bad_key", f"{key}: {e}")
            return
        with self._lock:
            self.received[kind] += 1
            if kind == "pose":
                d = pose_json(msg, now)
                self._pose[rid] = d
                self._changed_pose[rid] = d
                trail = self._trail.get(rid)
                if trail is None:
                    trail = self._trail[rid] = deque(maxlen=self.trail_points)
                trail.append([msg.t, d["x"], d["y"], msg.floor])
            else:
                d = status_json(msg, now)
                self._status[rid] = d
                self._changed_status[rid] = d

    def _reject(self, reason: str, detail: str) -> None:
        with self._lock:
            n = self.rejected[reason] = self.rejected.get(reason, 0) + 1
        if n <= LOG_REJECTS_PER_REASON:
            log.warning("console: ignored a message (%s): %s%s", reason, detail,
                        " (further ones of this reason are only counted)" if n == LOG_REJECTS_PER_REASON else "")

    # ------------------------------------------------------------------ page side
    def take_changes(self) -> dict | None:
        """Poses and statuses changed since the last call (latest each), or None when none did."""
        with self._lock:
            if not self._changed_pose and not self._changed_status:
                return None
            poses, statuses = list(self._changed_pose.values()), list(self._changed_status.values())
            self._changed_pose, self._changed_status = {}, {}
            rejected = dict(self.rejected)
        return {"poses": poses, "statuses": statuses, "rejected": rejected}

    def snapshot(self) -> dict:
        """Everything, for a page that has just connected."""
        with self._lock:
            return {"poses": list(self._pose.values()), "statuses": list(self._status.values()),
                    "trails": {rid: list(tr) for rid, tr in self._trail.items()}, "rejected": dict(self.rejected)}

    def device_time(self, responder: str) -> float | None:
        """The responder's latest device time the console has seen (its last Pose or Status)."""
        with self._lock:
            ts = [d["t"] for d in (self._pose.get(responder), self._status.get(responder)) if d is not None]
        return max(ts) if ts else None

    def floor_of(self, responder: str) -> int | None:
        with self._lock:
            p = self._pose.get(responder)
        return None if p is None else int(p["floor"])

    def latest(self, responder: str) -> tuple[dict | None, dict | None]:
        """The responder's latest pose and status as the page reads them (None: not yet)."""
        with self._lock:
            return self._pose.get(responder), self._status.get(responder)

    def responders(self) -> list[str]:
        with self._lock:
            return sorted(set(self._pose) | set(self._status))
