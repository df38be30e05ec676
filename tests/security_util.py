"""Helpers for the security tests: an incident PKI, a TLS router with the roster's access
control and the service on it, clients with a given identity, and a tap that records what
reaches the router."""
from __future__ import annotations

import contextlib
import json
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from pdr.synthetic import static_imu
from service.protocol import pki, wire
from service.protocol.access import access_control, access_message, load_roster
from service.protocol.incident import default_incident
from service.protocol.session import open_client, open_session
from service.protocol.tls import TlsIdentity
from service.shell.service import IncidentService, ServiceSettings
from tests.zenoh_util import free_port

INCIDENT = "demo"  # the default incident's id
DOOR = default_incident().checkpoints[0].name  # surveyed: with access enforced a wearable places itself only at one
PASSWORDS = {"alice": "alice-incident-pw", "vic": "vic-incident-pw"}


def make_pki(d: Path) -> Path:
    """The demo incident's CA and one identity of every role (operators' passwords known)."""
    pki.init_ca(d, INCIDENT)
    for role, name in (("service", "svc"), ("router", "zenohd"), ("wearable", "ff1"), ("wearable", "ff2"),
                       ("anchor", "a1"), ("console", "console-1"), ("simulator", "sim"), ("gateway", "gw")):
        pki.issue(d, role, name)
    pki.issue(d, "operator", "alice", password=PASSWORDS["alice"])
    pki.issue(d, "viewer", "vic", password=PASSWORDS["vic"])
    pki.reserve(d, "wearable", ["ff9"])  # a responder who may join later
    return d


def identity(d: Path, name: str) -> TlsIdentity:
    return TlsIdentity.load(d / name)


def tls_client(endpoint: str, ident: TlsIdentity) -> zenoh.Session:
    return open_client(endpoint, tls=ident)


def matched_publisher(session: zenoh.Session, key: str, timeout: float = 10.0):
    """A publisher on ``key`` once the service's subscription has reached it (zenoh drops what
    is put before the route exists; on a loaded machine that takes a while)."""
    pub = session.declare_publisher(key, reliability=zenoh.Reliability.RELIABLE,  # block, never drop, when
                                    congestion_control=zenoh.CongestionControl.BLOCK)  # the loaded machine lags
    deadline = time.monotonic() + timeout
    while not pub.matching_status.matching:
        if time.monotonic() > deadline:
            raise AssertionError(f"no subscriber reached the publisher of {key} within {timeout} s")
        time.sleep(0.02)
    return pub


def put_routed(session: zenoh.Session, key: str, payload: bytes, timeout: float = 10.0) -> None:
    """One message that must arrive (a positive control): put once the route to a subscriber
    exists, blocking rather than dropping (a fresh session's plain ``put`` goes nowhere until the
    router has told it of the subscription, which a loaded machine delays)."""
    pub = matched_publisher(session, key, timeout)
    try:
        pub.put(payload)
    finally:
        pub.undeclare()


def bare_tls_client(endpoint: str, ca: Path) -> zenoh.Session:
    """A TLS client that trusts the incident CA but presents no certificate of its own."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("transport/link/tls", json.dumps({"root_ca_certificate": str(ca)}))
    return zenoh.open(conf)


class Tap:
    """Everything that reaches the router's own session under ``firetrack/{incident}/**``:
    (key, payload). Published by the service itself too (its poses, statuses, audits)."""

    def __init__(self, session, incident: str = INCIDENT):
        self.items: list[tuple[str, bytes]] = []
        self._lock = threading.Lock()
        self.sub = session.declare_subscriber(f"firetrack/{incident}/**", self._on)

    def _on(self, s) -> None:
        with self._lock:
            self.items.append((str(s.key_expr), s.payload.to_bytes()))

    def keys(self) -> list[str]:
        with self._lock:
            return [k for k, _ in self.items]

    def payloads(self, key: str) -> list[bytes]:
        with self._lock:
            return [p for k, p in self.items if k == key]


@contextlib.contextmanager
def secure_service(d: Path, settings: ServiceSettings | None = None, recorder=None, incident=None):
    """A TLS router with the roster's access control (what ``serve --tls`` opens), the service
    on it as ``svc`` (for ``incident``, default the demo's), and a tap: (service, endpoint, tap)."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    roster = load_roster(d / "roster.json")
    session = open_session([endpoint], tls=identity(d, "svc"), acl=access_control(roster))
    tap = Tap(session)
    svc = IncidentService(session, incident or default_incident(), settings or ServiceSettings(warm_up=False),
                          recorder=recorder,
                          access=access_message(roster, str(d / "roster.json")), actor="svc").start()
    try:
        yield svc, endpoint, tap
    finally:
        svc.close()
        session.close()


def walking_frames(responder: str, seconds: float, t0: float = 1000.0, seed: int = 0, device: str | None = None,
                   seq0: int = 0, rate: float = 50.0) -> list[wire.ImuBatch]:
    """Synthetic frames of a person walking (a 1.8 Hz vertical bounce the step detector counts)."""
    imu = static_imu(seconds=seconds, rate_hz=rate, seed=seed)
    acc = imu.acc.copy()
    acc[:, 2] += 2.5 * np.sin(2 * np.pi * 1.8 * imu.t)
    return list(wire.imu_batches_from_arrays(responder, device or f"dev-{responder}", imu.t + t0, acc, imu.gyr,
                                             imu.mag, per_batch=5, seq0=seq0))
