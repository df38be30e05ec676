"""A standby that takes over, and the epoch that fences the service it replaced (issue 29, part 4).

Every one-process service (``serve``, or one ``serve --shard i/N``) claims an *epoch* for its
part of the incident: a liveliness token whose key names it, beside the responders' keys (a
five-chunk key, which no ``firetrack/{incident}/*/{kind}`` wildcard matches)::

    firetrack/{incident}/service/{k}.{n}/epoch/{e}.{nonce}   liveliness: this service publishes for part k of n
    firetrack/{incident}/service/{k}.{n}/snapshot            the primary's newest core snapshot (while one listens)

Claims are ordered by ``(e, nonce)``: a new claim takes ``e`` = 1 + the highest epoch any
service of that part has claimed (live now or seen before), and the random nonce orders two
claims made at once. A service that sees a live claim above its own is **fenced**: it stops
publishing poses and status at once (:meth:`IncidentService._publish`) and ``serve`` exits (code
3), so a primary that comes back from a pause or a partition stands down instead of publishing
beside the one that replaced it. Every pose and status carries its service's claim as zenoh's
attachment (``b"{e}.{nonce}"``), so anyone can tell who published it.

``serve --standby`` (and a ``serve`` that finds another claim live at its start) waits: it
follows the primary's snapshots (:class:`SnapshotFollower`; the primary pickles one every
``snapshot_every_s`` only while a follower matches its publisher) and its claim. When no
claim has been live for :data:`VACANT_S` (a primary killed or cut off: its router drops the
token when the link closes or its lease ends), the standby restores the newest snapshot,
claims the next epoch and starts serving. The wearables fill in what it missed: its advanced
subscribers fetch their kept frames (duplicates of what the snapshot holds are turned away by
the gate, not counted as rejects), and a gap zenoh's history reply loses is asked for by the
gate (``Status.missing``) and resent from the wearable's own keep. Fixes are not fetched
again (they carry no seq): a fix sent between the newest snapshot and the takeover is lost,
which is why the snapshot period is short.
"""
from __future__ import annotations

import logging
import secrets
import threading
import time

import zenoh

from service.protocol.keys import KEY_ROOT, check_id

log = logging.getLogger("firetrack.service")

VACANT_S = 1.0  # s without any live claim before a standby takes over
CLAIM_QUERY_S = 2.0  # s the liveliness query for the claims already made waits for replies


def part_root(incident: str, part: tuple[int, int]) -> str:
    k, n = part
    return f"{KEY_ROOT}/{check_id('incident', incident)}/service/{int(k)}.{int(n)}"


def claims_key(incident: str, part: tuple[int, int]) -> str:
    return f"{part_root(incident, part)}/epoch/*"


def snapshot_key(incident: str, part: tuple[int, int]) -> str:
    return f"{part_root(incident, part)}/snapshot"


def parse_claim(key: str) -> tuple[int, str] | None:
    """``.../epoch/{e}.{nonce}`` -> ``(e, nonce)``; None for anything else."""
    last = str(key).rsplit("/", 1)[-1]
    epoch, _, nonce = last.partition(".")
    return (int(epoch), nonce) if epoch.isdigit() and nonce else None


class Fence:
    """This service's claim of its part, and the watch on every other claim of it."""

    def __init__(self, session: zenoh.Session, incident: str, part: tuple[int, int]):
        self.session, self.incident, self.part = session, incident, tuple(part)
        self.claim_id: tuple[int, str] | None = None
        self.fenced = threading.Event()  # a higher claim is live: stop publishing
        self.fenced_by: tuple[int, str] | None = None
        self._live: set[tuple[int, str]] = set()
        self._highest = 0
        self._lock = threading.Lock()
        self._token = None
        self._sub = session.liveliness().declare_subscriber(claims_key(incident, part), self._on_claim, history=True)
        self._query()

    @property
    def epoch(self) -> int | None:
        return None if self.claim_id is None else self.claim_id[0]

    @property
    def tag(self) -> bytes | None:
        """The attachment of what this service publishes: its claim."""
        return None if self.claim_id is None else f"{self.claim_id[0]}.{self.claim_id[1]}".encode()

    def _query(self) -> None:
        """The claims live now (the subscriber's history comes asynchronously; this waits)."""
        for reply in self.session.liveliness().get(claims_key(self.incident, self.part), timeout=CLAIM_QUERY_S):
            if reply.ok is not None:
                self._note(parse_claim(str(reply.ok.key_expr)), True)

    def _on_claim(self, sample: zenoh.Sample) -> None:
        self._note(parse_claim(str(sample.key_expr)), sample.kind == zenoh.SampleKind.PUT)

    def _note(self, claim: tuple[int, str] | None, live: bool) -> None:
        if claim is None:
            return
        with self._lock:
            if live:
                self._live.add(claim)
                self._highest = max(self._highest, claim[0])
            else:
                self._live.discard(claim)
            mine = self.claim_id
        if live and mine is not None and claim > mine and not self.fenced.is_set():
            self.fenced_by = claim
            self.fenced.set()
            log.error("service epoch %d.%s of part %d/%d sees epoch %d.%s: it stands down and publishes no more",
                      mine[0], mine[1], *self.part, *claim)

    def others(self) -> set[tuple[int, str]]:
        """The live claims of other services of this part."""
        with self._lock:
            return {c for c in self._live if c != self.claim_id}

    def wait_vacant(self, stop: threading.Event | None = None, vacant_s: float = VACANT_S) -> bool:
        """Until no other claim has been live for ``vacant_s`` (True), or ``stop`` is set (False)."""
        since = None
        while stop is None or not stop.is_set():
            if self.others():
                since = None
            elif since is None:
                since = time.monotonic()
            elif time.monotonic() - since >= vacant_s:
                return True
            time.sleep(0.05)
        return False

    def claim(self) -> int:
        """Claim the next epoch of this part and declare it; returns it."""
        self._query()
        with self._lock:
            self.claim_id = (self._highest + 1, secrets.token_hex(4))
            above = max(self._live, default=None)
        self._token = self.session.liveliness().declare_token(
            f"{part_root(self.incident, self.part)}/epoch/{self.claim_id[0]}.{self.claim_id[1]}")
        if above is not None and above > self.claim_id:  # claimed above us between the query and now
            self._note(above, True)
        log.info("serving part %d/%d of incident %r at epoch %d", *self.part, self.incident, self.claim_id[0])
        return self.claim_id[0]

    def close(self) -> None:
        _undeclare(self._sub, self._token)


class SnapshotFeed:
    """The primary's side: its core's snapshots put on the part's snapshot key, but only while
    a standby subscribes (a snapshot costs the worker a pickle of every changed responder)."""

    def __init__(self, session: zenoh.Session, incident: str, part: tuple[int, int], tag: bytes | None):
        self.tag = tag
        self.published = 0
        self._pub = session.declare_publisher(snapshot_key(incident, part), congestion_control=zenoh.CongestionControl.BLOCK,
                                              reliability=zenoh.Reliability.RELIABLE)

    def wanted(self) -> bool:
        return bool(self._pub.matching_status.matching)

    def put(self, blob: bytes) -> None:
        self._pub.put(blob, attachment=self.tag)
        self.published += 1

    def close(self) -> None:
        _undeclare(self._pub)


class SnapshotFollower:
    """The standby's side: the newest snapshot the primary put (bytes, the claim that put it)."""

    def __init__(self, session: zenoh.Session, incident: str, part: tuple[int, int]):
        self.newest: bytes | None = None
        self.newest_from: str | None = None
        self.received = 0
        self._sub = session.declare_subscriber(snapshot_key(incident, part), self._on_snapshot)

    def _on_snapshot(self, sample: zenoh.Sample) -> None:
        self.newest = sample.payload.to_bytes()
        att = sample.attachment
        self.newest_from = att.to_bytes().decode(errors="replace") if att is not None else None
        self.received += 1

    def close(self) -> None:
        _undeclare(self._sub)


def _undeclare(*entities) -> None:
    for d in entities:
        if d is not None:
            try:
                d.undeclare()
            except Exception:  # closed with its session
                pass
