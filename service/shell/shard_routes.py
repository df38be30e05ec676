"""Which frames a worker subscribes to: with ``--workers K > 1``, only its own responders'.

A zenoh key expression cannot say "the ids that hash to worker k", so a worker does not ask
for ``firetrack/{incident}/*/imu`` (that would bring it every responder's frames, to be dropped
by key). Instead every worker watches the wearables' liveliness tokens
(``firetrack/{incident}/{responder}/presence``, declared by :mod:`client.wearable`), and when a
responder that is its own (:func:`service.shell.sharding.in_shard`, the one definition of who
owns an id) appears, it declares that responder's own advanced subscribers::

    token of r appears, in_shard(r, k, K) ──► declare  firetrack/{incident}/r/imu  (history + recovery)
                                                        firetrack/{incident}/r/fix  (recovery; history if r is new here)
    token of r gone, and the core let r go ──► undeclare both (bounded state)

The token is declared after the wearable's publishers, and the owner declares the subscribers
a moment later still; what was sent in between comes from the wearable's keep: the advanced
subscriber detects the advanced publisher (``detect_late_publishers``) and fetches it, as it
does for a service that starts after the wearable. When a live frame beats that reply, zenoh
drops the kept frames it overtook (the first-frames race); the gate then holds the stream's
first frame and asks the wearable for ``[0, seq - 1]`` (``CoreSettings.ask_from_start``), so
they are resent, or counted lost if the wearable no longer has them. Fixes are fetched from the keep only for a responder
this worker does not track yet (a fix already applied must not be applied twice after a new
declaration: fixes have no seq numbers).

While a wearable is away (its token gone: an outage) the subscribers stay: when it is back
their recovery fetches what it missed. They go only once the core has let the responder go.

What has no token. A plain publisher that announces nothing (a replay, a third-party device)
is invisible to a worker until it subscribes to its key; no key expression catches it without
catching everyone. ``ServiceSettings.catch_all`` keeps today's wildcard subscribers beside the
routes (each worker then takes the unannounced ids of its shard from them, and leaves the ids
it has a route for to the route): lossless for such sources, at today's cost of every frame
reaching every worker. Operator fixes need no catch-all: they come as ``op`` actions, which
the worker of the responder they name takes (:meth:`IncidentService._enqueue_op`).

Held by :class:`service.shell.service.IncidentService` (``svc.routes``).
"""
from __future__ import annotations

import logging

import zenoh
import zenoh.ext as zext

from service.protocol import wire

log = logging.getLogger("firetrack.service")


class ShardRoutes:
    """The frames' subscribers of a worker: the incident's wildcard (one worker, or the
    catch-all), and one route (imu + fix subscribers) per announced responder of its shard."""

    def __init__(self, session: zenoh.Session, incident_id: str, settings, shard: tuple[int, int], on_miss):
        self.session, self.id, self.settings, self.shard, self._on_miss = session, incident_id, settings, shard, on_miss
        self.imu = None  # the incident's frames' subscriber (a zenoh FIFO channel): one worker, or the catch-all
        self.fix = None  # the incident's fixes' subscriber
        self.routes: dict[str, tuple] = {}  # responder id -> its (imu, fix, miss listeners)
        self.routed_keys: set[str] = set()  # the keys those subscribers are on
        self.present: set[str] = set()  # own responders whose presence token is up
        self._misses: list = []  # the wildcard subscribers' miss listeners

    @property
    def sharded(self) -> bool:
        return self.shard[1] > 1

    def declare(self) -> None:
        """One worker: the incident's wildcard subscribers (every frame is its own). Several:
        none until a token announces one of its responders (and the wildcard only as a catch-all)."""
        if self.sharded and not self.settings.catch_all:
            return
        self.imu = self._advanced(wire.key_all(self.id, "imu"), "imu", history=True)
        # fixes: recovered after a miss, but never fetched again on detection (a fix applied
        # before a restart must not be applied twice; frames have seq numbers, fixes do not)
        self.fix = self._advanced(wire.key_all(self.id, "fix"), "fix", history=False)
        self._misses = [self.imu.sample_miss_listener(self._on_miss), self.fix.sample_miss_listener(self._on_miss)]

    def _advanced(self, key: str, kind: str, history: bool):
        st = self.settings
        size = st.imu_channel if kind == "imu" else st.fix_channel
        routed = key.rsplit("/", 2)[-2] != "*"
        if routed:  # one responder's: a smaller channel each
            size = max(1, size // 10)
        # Late publishers are detected on a route too: the route's first history query can reach
        # the router before the wearable's keep is known there (it then finds nothing, and a
        # wearable that has gone quiet would never be asked again). A second query may lose the
        # race with a live sample, after which zenoh drops the kept frames it overtook; the gate
        # asks for those (a gap, or a stream first heard above seq 0: service/core/gate.py).
        hist = zext.HistoryConfig(detect_late_publishers=True, max_samples=st.history_frames if kind == "imu"
                                  else None) if history else None
        # Recovery follows the wearables' heartbeats (their newest seq, sent when it changed), as the
        # wildcard's does. Periodic queries (one per route per second) made a thousand queries a
        # second at N = 1000, through the router and into the wearables' keeps, and stalled the
        # frames' delivery: 909 of 101 000 frames reached idle workers (issue 29, docs/capacity.md).
        recovery = zext.RecoveryConfig(heartbeat=True)
        return zext.declare_advanced_subscriber(self.session, key, zenoh.handlers.FifoChannel(size), history=hist,
                                                recovery=recovery, subscriber_detection=True)

    def wildcards(self):
        """``(kind, subscriber)`` of the incident's wildcard subscribers (one worker, or the catch-all)."""
        for kind, sub in (("imu", self.imu), ("fix", self.fix)):
            if sub is not None:
                yield kind, sub

    def route_pairs(self) -> list[tuple]:
        """``(imu, fix)`` subscribers of every route (the worker's thread takes frames from them)."""
        return [(imu, fix) for imu, fix, _ in self.routes.values()]

    def presence(self, parts, present: bool, tracked) -> None:
        """A token of one of this worker's responders came or went (the worker's thread): its
        route is declared when it comes; when it goes, :meth:`forget` decides later. ``parts``:
        the token's key as the shell read it (:class:`service.protocol.keys.KeyParts`).
        ``tracked``: the responders the core holds (their fixes are not fetched again)."""
        if isinstance(parts, ValueError):  # not a responder's token: the core says so when it takes it
            return
        rid = parts.responder
        if present:
            self.present.add(rid)
            if rid not in self.routes:
                self._declare_route(rid, rid in tracked)
        else:
            self.present.discard(rid)

    def _declare_route(self, rid: str, tracked: bool) -> None:
        try:
            imu = self._advanced(wire.key(self.id, rid, "imu"), "imu", history=True)
            fix = self._advanced(wire.key(self.id, rid, "fix"), "fix", history=not tracked)
            misses = [imu.sample_miss_listener(self._on_miss), fix.sample_miss_listener(self._on_miss)]
        except Exception:  # a closing session: no route, and the service carries on
            log.exception("declaring the subscribers of responder %s", rid)
            return
        self.routes[rid] = (imu, fix, misses)
        self.routed_keys.update((wire.key(self.id, rid, "imu"), wire.key(self.id, rid, "fix")))

    def forget(self, tracked) -> None:
        """Routes of responders whose token is gone and whom the core let go (not in ``tracked``)
        are undeclared."""
        gone = [r for r in self.routes if r not in self.present and r not in tracked]
        for rid in gone:
            self._undeclare_route(self.routes.pop(rid))
            self.routed_keys.difference_update((wire.key(self.id, rid, "imu"), wire.key(self.id, rid, "fix")))

    @staticmethod
    def _undeclare_route(route) -> None:
        imu, fix, misses = route
        for d in (*misses, imu, fix):
            try:
                d.undeclare()
            except Exception:  # already gone with a closed session
                pass

    def close(self) -> None:
        """Undeclare every frames' subscriber (after the worker took what waited in them)."""
        if self.imu is not None:
            self._undeclare_route((self.imu, self.fix, self._misses))
        self.imu = self.fix = None
        self._misses = []
        for route in self.routes.values():
            self._undeclare_route(route)
        self.routes.clear()
        self.routed_keys.clear()
